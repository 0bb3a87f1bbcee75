"""The README and the user guide say what the programs do: the README's results table is ``paper_scale.csv``'s, its
first screen names the commands, it stays short; the guide's sample estimate output has the lines the estimate prints
now (their labels, numbers aside), and the counts its estimate section quotes are the ones ``conf/estimate.yaml`` sets."""
from __future__ import annotations

import re
from pathlib import Path

from omegaconf import OmegaConf

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
GUIDE = ROOT / "docs" / "GUIDE.md"
SECTION = ("## Will it pay for my volume?", "## Using it on your own data")


def test_the_readme_results_table_is_the_csvs():
    """Between its markers the README holds exactly the table make bench-paper writes from benchmarks/paper_scale.csv."""
    from imls_lightning.pipelines.bench_paper import read_rows
    from imls_lightning.report.results_table import between, results_table

    got = between(README.read_text(encoding="utf-8"))
    assert got is not None, "README.md has no results markers"
    assert got == results_table(read_rows(ROOT / "benchmarks" / "paper_scale.csv"), current_only=True).strip(), (
        "README.md's results table disagrees with benchmarks/paper_scale.csv: run make bench-paper summarize_only=true")


def test_the_readme_first_screen_says_what_how_and_where_it_pays():
    lines = README.read_text(encoding="utf-8").splitlines()
    assert len(lines) <= 300, f"README.md has {len(lines)} lines (at most 300: the rest belongs under docs/)"
    first = "\n".join(lines[:60])
    for needle in ("make demo", "make test", "make reproduce", "fastest", "results:begin"):
        assert needle in first, f"README.md's first screen (60 lines) lacks {needle!r}"
    for target in re.findall(r"\]\(([^)#:]+)\)", "\n".join(lines)):  # every relative link resolves
        assert (ROOT / target).exists(), f"README.md links to {target}, which does not exist"


def _section() -> str:
    text = GUIDE.read_text(encoding="utf-8")
    start, end = text.index(SECTION[0]), text.index(SECTION[1])
    return text[start:end]


def _sample() -> list[str]:
    """The estimate's sample output in docs/GUIDE.md: the code block after "The output for the built-in"."""
    section = _section()
    after = section[section.index("The output for the built-in"):]
    block = after[after.index("```") + 3:]
    return [ln for ln in block[block.index("\n") + 1:block.index("```")].splitlines() if ln.strip()]


def label(line: str) -> str:
    """What a line of the estimate's output says, without its numbers: numbers become ``#`` (a row of them one ``#…``),
    and what follows the first ``:``, ``;``, ``,`` or ``(`` (the scene's, the method's own words) is dropped.

    Example:
        >>> label("  speed-up      2.95  2.30  1.88"), label("  full frame 2173 ms; C pattern 594.0 ms")
        ('speed-up #…', 'full frame # ms')
    """
    s = re.sub(r"[-+]?\d+(?:\.\d+)?", "#", line.strip())
    s = re.split(r"[:;,(]", s, maxsplit=1)[0]
    s = re.sub(r"(?:#%?x?\s*){2,}", "#… ", s)
    return " ".join(s.split())


def _estimate() -> dict:
    """An estimate with every part the guide's sample shows (seed_whole's, as make bench-paper asks it): the bound with
    its two renders, the sharpened masks' curve and its interval over the views, the needed share, both ray casters;
    no quick RecNN, no candidates."""
    shares = [round(0.1 * i, 1) for i in range(1, 11)]
    bound = [{"share": s, "speedup": 3.0 - 2 * s} for s in shares]
    return {
        "scene": "rayleigh_taylor", "volume_dims": "512x512x512", "recnn": "enhancenet", "pattern": "downsample",
        "fr_size": 512, "c_size": 256, "full_frame_ms": 2173.0, "c_render_ms": 594.0, "object_fraction": 0.83,
        "upsampler": "bilinear", "bilinear_db": 34.45, "nets_ms": 74.7, "ims_ms": 16.1, "decoder_ms": 58.6,
        "recnn_ms": 91.7, "render_to_nets": 8.0, "bound": bound, "limit": bound, "bound_silhouette": bound,
        "bound_modelled": bound, "per_view": [{}] * 18,
        "bound_interval": [{"share": s, "low": 1.0, "high": 2.0} for s in shares],
        "recnn_lead": None, "by_sharpness": {"3": {"bound": bound}},
        "ray_casters": {"skip": {"c_render_ms": 76.9, "bound": bound}, "noskip": {"c_render_ms": 1107.8, "bound": bound},
                        "fastest_recnn": "skip", "vs_fastest": bound, "free_networks_vs_fastest": bound,
                        "speedup_vs_fastest_at_needed": 0.99},
        "needed": {"reference": "bilinear", "epsilon_db": 1.0,
                   "rows": [{"kept": s / 2, "gap_db": 1.0, "render_ms": None} for s in [x for x in shares for _ in (0, 1)]]},
        "needed_share": 0.24, "speedup_at_needed": 0.99, "bound_at_needed": 0.97, "share_for_target": None, "target": 2.0,
    }


def test_the_readme_sample_estimate_has_the_lines_the_estimate_prints():
    from imls_lightning.estimate.run import format_report

    printed = format_report(_estimate()).splitlines()
    sample = _sample()
    assert sample[-1].endswith("/estimate.json")  # the last line: estimate.json's path
    want = [label(ln) for ln in printed[1:]]
    got = [label(ln) for ln in sample[1:-1]]
    assert got == want, ("docs/GUIDE.md's sample estimate output is not what python -m imls_lightning.estimate prints now; "
                         f"lines it lacks: {[w for w in want if w not in got]}, lines it has that are no longer printed: "
                         f"{[g for g in got if g not in want]}")


def test_the_readme_quotes_the_estimates_counts_of_views():
    cfg = OmegaConf.load(ROOT / "conf" / "estimate.yaml")
    section = _section()
    quoted = [int(n) for n in re.findall(r"(\d+) random views", section)]
    assert quoted and all(n == cfg.views for n in quoted), (f"conf/estimate.yaml: views={cfg.views}; docs/GUIDE.md's estimate "
                                                            f"section says {quoted} random views")
    frames = [int(n) for n in re.findall(r"full frame on (\d+) of them", section)]
    assert frames and all(n == cfg.frame_views for n in frames), (f"conf/estimate.yaml: frame_views={cfg.frame_views}; "
                                                                  f"docs/GUIDE.md says {frames}")
    over = [int(n) for n in re.findall(r"over the (\d+) views resampled", "\n".join(_sample()))]
    assert all(n == cfg.views for n in over), f"the sample's interval is over {over} views, views={cfg.views}"
