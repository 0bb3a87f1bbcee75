"""The stages of a pipeline: the commands a user would type, run one after the other through the real
CLIs (:func:`run_stage`; :func:`dry_stage` prints them instead), their shared arguments
(:func:`stage_args`, :func:`stage_overrides`, :func:`sparser_overrides`), the scene overrides every
pipeline passes to every stage (:func:`split_scene_overrides`, :func:`check_scene_overrides`), the
evaluation's results the later stages read (:func:`read_summary`) and a pipeline CLI's body
(:func:`run_pipeline`)."""
from __future__ import annotations

import codecs
import os
import re
import shlex
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Sequence

from omegaconf import DictConfig, OmegaConf

from imls_lightning.base.errors import HYDRA_FLAGS_WITH_VALUE, INTERRUPTED_EXIT, PIPELINE_STAGE_ENV, InputError, exit_interrupted
from imls_lightning.base.overrides import quote_override_value

from ..orp.overrides import override_key


class StageFailed(RuntimeError):
    """A stage's command exited with an error; its own message was already printed."""


class StageUnfinished(RuntimeError):
    """A training stage trained one chunk (``chunk_minutes``) and exited with status 3: the pipeline stops
    there, and the same command continues it."""

    EXIT_CODE = 3


# ------------------------------------------------------------------------------------------------
# scene overrides: the pipelines take every scene override python -m data_gen takes

#: ``scene.<key>=...`` with Hydra's prefixes (``+`` add, ``++`` force-add, ``~`` delete)
_SCENE_OVERRIDE = re.compile(r"(?:\+\+|\+|~)?scene\.[A-Za-z_]")


def split_scene_overrides(argv: Sequence[str]) -> tuple[list[str], list[str]]:
    """Split a pipeline's command line into its own arguments and the scene overrides.

    The pipelines' configs hold ``scene`` as a plain preset name, so Hydra would refuse
    ``scene.volume.path=...`` ("Key 'volume' is not in struct"); the scene overrides are taken out
    and passed, verbatim, to the stage commands (whose configs compose the ``scene`` group).

    Example:
        >>> split_scene_overrides(["scene=file", "scene.volume.path=/d/a b.nii.gz", "data=tiny", "~scene.volume.dims"])
        (['scene=file', 'data=tiny'], ['scene.volume.path=/d/a b.nii.gz', '~scene.volume.dims'])
    """
    own: list[str] = []
    scene: list[str] = []
    value_of_flag = False
    for a in argv:
        if value_of_flag or not _SCENE_OVERRIDE.match(a):
            own.append(a)
            value_of_flag = not value_of_flag and a in HYDRA_FLAGS_WITH_VALUE
        else:
            scene.append(a)
    return own, scene


def check_scene_overrides(scene: str, overrides: Sequence[str]) -> None:
    """Compose ``python -m data_gen``'s config with ``scene=<scene>`` and ``overrides`` in this
    process, so a bad override stops the pipeline before any stage runs, with Hydra's message.

    Raises:
        InputError: the scene preset does not exist or an override does not apply to it.
    """
    if not overrides:
        return
    from data_gen.scenes import preset_config

    preset_config(scene, overrides, context=f"scene overrides {' '.join(overrides)} (scene={scene})")


def dry_stage(name: str, args: Sequence[str], log=sys.stderr, tag: str = "demo") -> str:
    """``dry_run=true``: print the stage's command (shell-quoted) on stdout instead of running it;
    its result is the placeholder ``<name>`` (spaces as ``-``)."""
    print(shlex.join(["python", *args]), flush=True)
    return f"<{'-'.join(name.split())}>"


def run_stage(name: str, args: Sequence[str], log=sys.stderr, tag: str = "demo") -> str:
    """Run ``python <args>``, echo its stdout, and return its last stdout line (the stage's result).

    ``tag`` prefixes the progress lines (``[demo]``, ``[bench]``)."""
    cmd = [sys.executable, *args]
    print(f"\n[{tag}] {name}: {' '.join(args)}", file=log, flush=True)
    t0 = time.perf_counter()
    # a stage stopped by Ctrl-C exits 130 without a line of its own: the pipeline says what was kept (run_pipeline)
    env = dict(os.environ, PYTHONUNBUFFERED="1", **{PIPELINE_STAGE_ENV: "1"})
    with subprocess.Popen(cmd, cwd=os.getcwd(), env=env, stdout=subprocess.PIPE) as proc:
        assert proc.stdout is not None
        last = _echo(proc.stdout, log)
        code = proc.wait()
    if code in (INTERRUPTED_EXIT, -signal.SIGINT):  # the stage alone was stopped by Ctrl-C: so is the pipeline
        raise KeyboardInterrupt
    if code == StageUnfinished.EXIT_CODE:
        raise StageUnfinished(f"{tag} stage '{name}' trained one chunk of its schedule; run the same command again to continue")
    if code != 0:
        raise StageFailed(f"{tag} stage '{name}' failed (exit {code}); its message is above. Command: python {' '.join(args)}")
    print(f"[{tag}] {name} done in {time.perf_counter() - t0:.1f} s -> {last}", file=log, flush=True)
    return last


def _echo(stream, log) -> str:
    """Copy a child's stdout to ``log`` indented, keeping its carriage returns (progress bars redraw
    in place instead of printing a line per update); returns its last non-empty line."""
    decoder = codecs.getincrementaldecoder("utf-8")(errors="replace")
    current, last, line_start = "", "", True
    while chunk := stream.read1(65536):
        for piece in re.split(r"([\r\n])", decoder.decode(chunk)):
            if piece in ("\r", "\n"):
                if piece == "\n" and current.strip():
                    last = current.strip()
                current, line_start = "", True
                log.write(piece)
            elif piece:
                if line_start:
                    log.write("  ")
                    line_start = False
                current += piece
                log.write(piece)
        log.flush()
    if current.strip():
        last = current.strip()
    return last


def override_list(cfg: DictConfig, key: str) -> list[str]:
    """The list of overrides at ``key`` of the demo/bench config (``[]`` when unset), as strings. An item that is
    itself a list is spliced in its place: a benchmark row composes the shared protocol's lists with its own settings
    (``iml: ['${protocol.iml}', trainer.max_epochs=15]``, conf/pipelines/protocol).

    Example:
        >>> cfg = OmegaConf.create({"protocol": {"iml": ["model.depth=4", "model.mean=0.2"]},
        ...                         "stages": {"iml": ["${protocol.iml}", "trainer.max_epochs=15"]}})
        >>> override_list(cfg, "stages.iml")
        ['model.depth=4', 'model.mean=0.2', 'trainer.max_epochs=15']
    """
    v = OmegaConf.select(cfg, key)
    if v is None:
        return []
    if not OmegaConf.is_list(v):
        raise InputError(f"{key}={v}: expected a list of overrides; on the command line quote each one: \"{key}=['trainer.max_epochs=5']\"")
    return [str(y) for x in v for y in (x if OmegaConf.is_list(x) else [x])]


def stage_overrides(cfg: DictConfig, name: str) -> list[str]:
    """The overrides of stage ``name``: ``stages.<name>``, then ``scene_stages.<scene>.<name>``
    ("model only what a scene requires"), whose keys replace the same keys of the first list.

    Example:
        >>> cfg = OmegaConf.create({"scene": "ct_head", "stages": {"iml": ["model.depth=4", "model.base_channels=8"]},
        ...                         "scene_stages": {"ct_head": {"iml": ["model.base_channels=16"]}}})
        >>> stage_overrides(cfg, "iml")
        ['model.depth=4', 'model.base_channels=16']
    """
    merged = {override_key(o): o for o in override_list(cfg, f"stages.{name}")}
    scene = cfg.get("scene")
    if scene is not None and OmegaConf.select(cfg, f"scene_stages.{scene}") is not None:
        merged.update({override_key(o): o for o in override_list(cfg, f"scene_stages.{scene}.{name}")})
    return list(merged.values())


def ims_decoder_overrides(cfg: DictConfig) -> list[str]:
    """The training overrides of the IMS's decoder stage: the IMS stage's own (the same networks and views), the
    decoder alone trained (``model.train_generator=false``), then ``stages.ims_decoder``'s (whose keys replace the same
    keys before them); the caller adds ``model.init_checkpoint``, the IMS it starts from.

    Example:
        >>> cfg = OmegaConf.create({"stages": {"ims": ["model.decoder_lr=1e-3", "trainer.max_epochs=5"],
        ...                                    "ims_decoder": ["trainer.max_epochs=2"]}})
        >>> ims_decoder_overrides(cfg)
        ['model.decoder_lr=1e-3', 'trainer.max_epochs=2', 'model.train_generator=false']
    """
    ordered = [*stage_overrides(cfg, "ims"), "model.train_generator=false", *stage_overrides(cfg, "ims_decoder")]
    return list({override_key(o): o for o in ordered}.values())


def ims_finetune_overrides(cfg: DictConfig) -> list[str]:
    """The training overrides of the IMS's fine-tuning stage: the IMS stage's own (the same networks, views and
    losses), then ``stages.ims_finetune``'s (whose keys replace the same keys before them: a lower ``model.lr``, its
    epochs); the caller adds ``model.init_checkpoint``, the IMS it starts from. The generator trains on (a step decay
    of the learning rate as a stage of its own, so the constant-rate stage before it can still be extended).

    Example:
        >>> cfg = OmegaConf.create({"stages": {"ims": ["model.lr=1e-3", "trainer.max_epochs=24"],
        ...                                    "ims_finetune": ["model.lr=1e-4", "trainer.max_epochs=3"]}})
        >>> ims_finetune_overrides(cfg)
        ['model.lr=1e-4', 'trainer.max_epochs=3']
    """
    ordered = [*stage_overrides(cfg, "ims"), *stage_overrides(cfg, "ims_finetune")]
    return list({override_key(o): o for o in ordered}.values())


#: the sparser pattern of each RecNN kind, as overrides of its training. EnhanceNet 4x instead of 2x: a quarter of
#: the C-pixels (one pixel of every 4x4 block). FoVolNet: half of them (a C-Image 1/sqrt(2) of the side). A quarter
#: (half the side) cannot hold the foveal pattern: its base level alone is 7% of the FR pixels, a quarter of C 6.25%.
SPARSER_PATTERN = {"enhancenet": ["pattern.factor=4"], "fovolnet": ["pattern.c_size_ratio=0.3536"]}


def sparser_overrides(cfg: DictConfig) -> list[str]:
    """The training overrides of the RecNN on a sparser pattern: the RecNN stage's own (trained the same
    way), the sparser pattern of its kind (:data:`SPARSER_PATTERN`), then ``stages.recnn_sparser``'s
    (whose keys replace the same keys before them).

    Example:
        >>> cfg = OmegaConf.create({"recnn": "enhancenet", "stages": {"recnn": ["trainer.max_epochs=10"], "recnn_sparser": []}})
        >>> sparser_overrides(cfg)
        ['trainer.max_epochs=10', 'pattern.factor=4']
    """
    kind = str(cfg.recnn)
    if kind not in SPARSER_PATTERN:
        raise InputError(f"recnn={kind}: no sparser pattern known for it (expected one of {sorted(SPARSER_PATTERN)}); "
                         "set stages.recnn_sparser=null to skip the sparser-pattern RecNN")
    ordered = [*stage_overrides(cfg, "recnn"), *SPARSER_PATTERN[kind], *stage_overrides(cfg, "recnn_sparser")]
    return list({override_key(o): o for o in ordered}.values())


#: ``renderer.<key>=<value>``, the only form :func:`renderer_overrides` takes
_RENDERER_OVERRIDE = re.compile(r"renderer\.[A-Za-z_][A-Za-z0-9_.]*=.+")


def renderer_overrides(cfg: DictConfig) -> list[str]:
    """The pipeline's ``renderer_overrides`` (``renderer.<key>=<value>``, e.g. ``renderer.interpolation=tricubic``):
    the renderer settings every stage's command gets after ``renderer=<name>``, the cache and the training included,
    since they may change the pixels; ``[]`` when the pipeline has none. A malformed one is refused in one line.

    Example:
        >>> renderer_overrides(OmegaConf.create({"renderer_overrides": ["renderer.interpolation=tricubic"]}))
        ['renderer.interpolation=tricubic']
        >>> renderer_overrides(OmegaConf.create({}))
        []
    """
    found = cfg.get("renderer_overrides") or []
    if not (OmegaConf.is_list(found) or isinstance(found, (list, tuple))):
        raise InputError(f"renderer_overrides={found!r}: expected a list of renderer.<key>=<value>")
    out = [str(o) for o in found]
    for o in out:
        if not _RENDERER_OVERRIDE.fullmatch(o):
            raise InputError(f"renderer_overrides: {o!r} is not renderer.<key>=<value> (e.g. renderer.interpolation=tricubic)")
    return out


def stage_args(cfg: DictConfig, scene_overrides: Sequence[str] = (), *, scene: str | None = None, recnn: bool = True,
               quote: bool = False, common: Sequence[str] = (), train: Sequence[str] = ()) -> tuple[list[str], list[str]]:
    """The arguments every stage's command shares: ``(common, train_common)``, the scene, data,
    renderer (with :func:`renderer_overrides`) and cache for every CLI, plus the RecNN, runs folder, seed (and no progress bar) for
    ``imls_lightning.train``.

    ``scene`` replaces ``cfg.scene`` (a benchmark runs several); ``recnn=False`` leaves ``recnn=`` to the
    caller (a benchmark trains several); ``quote`` quotes the paths as Hydra override values; ``common``
    and ``train`` are overrides appended to each list (``train`` before ``trainer.enable_progress_bar``).

    Example:
        >>> cfg = OmegaConf.create({"scene": "flame", "data": "tiny", "renderer": "numba", "cache_dir": "c",
        ...                         "recnn": "enhancenet", "runs_dir": "r", "seed": 0, "progress": True})
        >>> stage_args(cfg, ["scene.name=f"])[1]
        ['scene=flame', 'scene.name=f', 'data=tiny', 'renderer=numba', 'data.cache_dir=c', 'recnn=enhancenet', 'paths.runs_dir=r', 'seed=0']
    """
    q = quote_override_value if quote else str
    shared = [f"scene={cfg.scene if scene is None else scene}", *scene_overrides, f"data={cfg.data}", f"renderer={cfg.renderer}",
              *renderer_overrides(cfg), f"data.cache_dir={q(str(cfg.cache_dir))}", *common]
    train_common = [*shared, *([f"recnn={cfg.recnn}"] if recnn else []), f"paths.runs_dir={q(str(cfg.runs_dir))}",
                    f"seed={int(cfg.seed)}", *train]
    if not cfg.progress:
        train_common.append("trainer.enable_progress_bar=false")
    return shared, train_common


def read_summary(report: Path) -> dict:
    """The evaluation's ``summary.json`` beside ``report``; a missing or damaged one is refused in one line."""
    import json

    path = Path(report).parent / "summary.json"
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError) as err:
        raise InputError(f"{path}: cannot read the evaluation's summary ({err}); run the evaluation again (reuse=false)") from None
    if not isinstance(data, dict) or "methods" not in data:
        raise InputError(f"{path}: not an evaluation summary (no 'methods'); run the evaluation again (reuse=false)")
    return data


def evaluation_lift(report: Path) -> bool:
    """Whether the evaluation beside ``report`` lifted the IMS's masks for its ORP (``summary.json``'s
    ``orp.lift``; False when it did not say), so later stages serve the same masks."""
    return bool((read_summary(report).get("orp") or {}).get("lift", False))


#: what a pipeline keeps when Ctrl-C stops it (:func:`run_pipeline`)
PIPELINE_KEPT = ("the stages that finished are kept (each command reuses its finished run; a training continues from its "
                 "last.ckpt, an evaluation from its partial results); run the same command again to continue")


def run_pipeline(body) -> None:
    """A pipeline CLI's body: run ``body()``; a failed stage exits 1 with its one-line message, a stage
    that trained one chunk exits 3 (run again to continue), Ctrl-C exits 130 with one line saying what was kept
    (:data:`PIPELINE_KEPT`), and the result (a report's path, None on a dry run) is the last line of stdout."""
    try:
        result = body()
    except KeyboardInterrupt:
        exit_interrupted(PIPELINE_KEPT)
    except StageUnfinished as err:
        print(f"[pipeline] {err}", file=sys.stderr, flush=True)
        sys.exit(StageUnfinished.EXIT_CODE)
    except StageFailed as err:
        print(f"error: {err}", file=sys.stderr, flush=True)
        sys.exit(1)
    if result is not None:
        print(result, flush=True)
