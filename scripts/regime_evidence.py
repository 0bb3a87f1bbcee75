"""Is a scene in the paper's regime? The classical upsampling against a trained RecNN on a cache's test views.

For a finished cache (``python -m data_gen``) and, optionally, RecNN run directories trained on it, prints per
method the mean PSNR over the cache's test trajectory: the classical C -> FR upsampling of the estimate
(:func:`imls_lightning.estimate.measure.upsample_c_image`: bilinear for the downsampling pattern, the pull-push
fill at the FR positions for the others) and each RecNN's own test PSNR (its ``result.json``), with the RecNN's
lead over the upsampling. Issue 31's bar: the upsampling at most 35 dB, the RecNN 30-40 dB and at least 2 dB
above it. ``--pattern foveal`` scores FoVolNet's pattern (``conf/pattern/<name>.yaml``). ``--json`` writes the numbers;
``--error-map PNG`` draws where the error lies on one test view (a crop: the truth, then the upsampling's and the
first RecNN's absolute error x8): along edges a RecNN can remove it, as speckle it cannot.

    python scripts/regime_evidence.py cache/rayleigh_taylor-741027e0c9e6 runs/paper/recnn-enhancenet-rayleigh_taylor-*
    python scripts/regime_evidence.py cache/rayleigh_taylor-92e343a2e4f7 runs/paper/recnn-fovolnet-* --pattern foveal
    python scripts/regime_evidence.py cache/seed_shell-2ccf21d2b406 runs/paper/recnn-enhancenet-seed_shell-38d323e5 \
        --error-map benchmarks/paper_regime_error_seed_shell.png
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from data_gen.cache_reader import ViewImageCache  # noqa: E402
from data_gen.errors import InputError, cli_errors  # noqa: E402
from imls_lightning.core.compaction import compact  # noqa: E402
from imls_lightning.core.patterns import SamplingPattern, build_pattern  # noqa: E402
from imls_lightning.estimate.measure import frame_tensor, psnr_db, upsample_c_image  # noqa: E402


def pattern_named(name: str, fr_size: int) -> SamplingPattern:
    """The sampling pattern of ``conf/pattern/<name>.yaml`` at ``fr_size`` (refused in one line if there is none)."""
    from omegaconf import OmegaConf

    path = ROOT / "conf" / "pattern" / f"{name}.yaml"
    if not path.is_file():
        known = sorted(p.stem for p in path.parent.glob("*.yaml"))
        raise InputError(f"--pattern {name}: expected one of {known}")
    return build_pattern(OmegaConf.load(path), fr_size)


def upsampling_psnr(cache: ViewImageCache, pattern: SamplingPattern | None = None,
                    max_views: int | None = None) -> tuple[list[float], str]:
    """Per test view: PSNR of the classical upsampling of the pattern's C-Image (default: the downsampling
    pattern, factor 2) against the FR image, and the upsampling's name."""
    _, images = cache.split("test")
    if max_views:
        images = images[np.linspace(0, len(images) - 1, max_views).round().astype(int)]
    pattern = pattern or pattern_named("downsample", cache.resolution)
    out, name = [], ""
    for img in images:
        fr = frame_tensor(img)
        up, name = upsample_c_image(compact(fr, pattern.indices, pattern.c_size), pattern)
        out.append(psnr_db(up, fr))
    return out, name


def trained_on(result: dict) -> list[str]:
    """The cache keys a run trained (and was tested) on: recorded by the train CLI, or, for a run made before it
    recorded them, computed from the scene, data and renderer settings in its ``result.json``."""
    if result.get("caches"):
        return list(result["caches"])
    from data_gen.cache_keys import cache_key
    from data_gen.scene import build_scene

    cfg = result.get("config") or {}
    return [cache_key(build_scene(cfg["scene"]), cfg["data"], cfg["renderer"])]


def recnn_row(run: Path, cache_hash: str | None = None) -> dict:
    """A RecNN run's test PSNR and size from its ``result.json`` (refused in one line if it is not one, or if it
    was trained and tested on another cache than ``cache_hash``: its PSNR would be on other views of other pixels)."""
    try:
        r = json.loads((run / "result.json").read_text())
        psnr = float(r["test"]["test/fr_psnr"])
    except (OSError, ValueError, KeyError, TypeError) as err:
        raise InputError(f"{run}: not a finished RecNN run with a test PSNR ({err})") from None
    if cache_hash is not None:
        keys = trained_on(r)
        if cache_hash not in keys:
            raise InputError(f"{run}: trained and tested on cache {', '.join(keys)}, not {cache_hash}; its test PSNR "
                             "is not on this cache's views (train it on this cache's settings)")
    net = r.get("config", {}).get("recnn", {}).get("net", {})
    return {"run": str(run), "net": {k: v for k, v in net.items() if k != "_target_"}, "psnr_db": psnr,
            "train_minutes": r.get("train_minutes"), "epochs": r.get("epochs")}


def error_map(cache: ViewImageCache, run: Path, pattern: SamplingPattern, path: Path, view: int = 30, crop: int = 192) -> Path:
    """Test view ``view``, a ``crop`` x ``crop`` crop at the centre: the truth | |upsampling - truth| x8 |
    |RecNN - truth| x8 (the RecNN: the run's best checkpoint), as a PNG."""
    from PIL import Image

    from data_gen.atomic import atomic_write
    from imls_lightning.inference.checkpoints import load_recnn

    _, images = cache.split("test")
    if not 0 <= view < len(images):
        raise InputError(f"--error-view {view}: expected 0 .. {len(images) - 1} (the cache's test views)")
    ckpt = json.loads((run / "result.json").read_text())["best_checkpoint"]
    recnn, _ = load_recnn(ckpt)
    fr = frame_tensor(images[view])
    c = compact(fr, pattern.indices, pattern.c_size)
    with torch.inference_mode():
        rec = recnn.eval()(c).clamp(0, 1)
    up, _ = upsample_c_image(c, pattern)
    crop = min(int(crop), cache.resolution)
    a = (cache.resolution - crop) // 2
    window = (slice(None), slice(None), slice(a, a + crop), slice(a, a + crop))

    def tile(x: torch.Tensor, gain: float = 1.0) -> np.ndarray:
        t = (x[window][0].permute(1, 2, 0).clamp(0, 1 / gain).numpy() * gain * 255 + 0.5).astype(np.uint8)
        return t if t.shape[-1] == 3 else np.repeat(t, 3, axis=-1)

    err = lambda x: (x - fr).abs().mean(1, keepdim=True)  # noqa: E731
    sheet = Image.fromarray(np.concatenate([tile(fr), tile(err(up), 8.0), tile(err(rec), 8.0)], axis=1))
    return atomic_write(path, lambda f: sheet.save(f, format="PNG"))


@cli_errors
def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("cache", type=Path)
    ap.add_argument("runs", type=Path, nargs="*")
    ap.add_argument("--max-views", type=int, default=None, help="test views scored (evenly spaced; default all)")
    ap.add_argument("--pattern", default="downsample", help="the RecNNs' pattern, conf/pattern/<name>.yaml (default downsample)")
    ap.add_argument("--json", type=Path, default=None)
    ap.add_argument("--error-map", type=Path, default=None, help="a PNG: truth | upsampling error x8 | first RecNN's x8")
    ap.add_argument("--error-view", type=int, default=30, help="the test view of --error-map (default 30)")
    a = ap.parse_args()
    if a.error_map is not None and not a.runs:
        raise InputError("--error-map: expected a RecNN run to draw (give its directory after the cache)")
    cache = ViewImageCache.open(a.cache)
    up, name = upsampling_psnr(cache, pattern_named(a.pattern, cache.resolution), max_views=a.max_views)
    mean = float(np.mean(up))
    rows = [recnn_row(r, cache.manifest["hash"]) for r in a.runs]
    print(f"{cache.path.name}: {name} C->FR ({a.pattern} pattern) {mean:.2f} dB (min {min(up):.2f}, max {max(up):.2f}) "
          f"on {len(up)} test views")
    for r in rows:
        print(f"  RecNN {r['net']}: {r['psnr_db']:.2f} dB ({r['psnr_db'] - mean:+.2f} dB over {name}), "
              f"{r['epochs']} epochs in {r['train_minutes']:.1f} min")
    if a.json:
        a.json.write_text(json.dumps({"cache": str(cache.path), "pattern": a.pattern, "upsampling": name,
                                      f"{name.replace('-', '_')}_db": mean, f"{name.replace('-', '_')}_db_per_view": up,
                                      "recnns": rows}, indent=1))
    if a.error_map is not None:
        print(f"  error map: {error_map(cache, a.runs[0], pattern_named(a.pattern, cache.resolution), a.error_map, a.error_view)}")


if __name__ == "__main__":
    main()
