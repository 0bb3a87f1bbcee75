"""Gap to the RecNN alone against the share of C: the estimate's untrained masks beside the trained pairs' points.

Each curve is a JSON of ``scripts/needed_share_check.py`` or an ``estimate.json`` (its ``needed`` rows); each
point is ``label:share:gap`` (a trained method's measured C-share and test gap, from its evaluation report).

    python scripts/needed_share_plot.py benchmarks/needed_share/ct_head_gap_vs_share.png \
        "C-Image importance + fill (test)=benchmarks/needed_share/ct_head_trained_recnn.json" \
        --point "IML/S + RecNN (ORP):0.806:0.53"
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from data_gen.errors import InputError, cli_errors  # noqa: E402


def curve(path: Path) -> tuple[list[float], list[float]]:
    """``(kept shares, mean gaps)`` of a check JSON or an estimate.json."""
    try:
        data = json.loads(path.read_text())
        rows = (data.get("needed") or {}).get("rows") if "needed" in data else data["rows"]
        return [r["kept"] for r in rows], [r["gap_db"] for r in rows]
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        raise InputError(f"{path}: expected a JSON of scripts/needed_share_check.py or an estimate.json with needed rows") from None


@cli_errors
def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("png", type=Path)
    ap.add_argument("curves", nargs="+", help="label=path.json")
    ap.add_argument("--point", action="append", default=[], help="label:share:gap (dB)")
    ap.add_argument("--epsilon", type=float, default=1.0)
    a = ap.parse_args()
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4.2), dpi=120)
    for item in a.curves:
        label, sep, path = item.partition("=")
        if not sep:
            raise InputError(f"{item!r}: expected label=path.json")
        x, y = curve(Path(path))
        ax.plot([100 * v for v in x], y, marker=".", label=label)
    for item, colour in zip(a.point, ["black", "tab:red", "tab:purple", "tab:brown", "tab:grey"] * 4):
        try:
            label, share, gap = item.rsplit(":", 2)
            ax.scatter([100 * float(share)], [float(gap)], s=60, marker="D", zorder=3, color=colour, label=label)
        except ValueError:
            raise InputError(f"--point {item!r}: expected label:share:gap") from None
    ax.axhline(a.epsilon, color="grey", lw=0.8, ls="--")
    ax.set_xlabel("share of the C-Image ray-cast (%)")
    ax.set_ylabel("PSNR gap to the RecNN alone (dB)")
    ax.set_ylim(0, 6)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    a.png.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(a.png)
    print(a.png)


if __name__ == "__main__":
    main()
