"""Commit a row: the networks of a finished evaluation and the operating point it chose, packed for the repository
(``python -m imls_lightning.pack_row evaluation=<folder> name=<row>``), and ``conf/row/<row>.yaml`` that
``python -m imls_lightning.reproduce row=<row>`` reads.

Packing keeps what inference needs and drops what only resuming a training needs (optimizer and scheduler states,
loop and callback states): the weights are the same tensors, checked one by one, so the packed network is the
evaluated one. The point's ``summary.json`` then names the packed files' SHA-256 (``checkpoints_sha256``) and keeps
the evaluated files' under ``packed_from``; ``config.yaml`` names the packed files.
"""
from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Mapping, Sequence

import torch
from omegaconf import OmegaConf

from imls_lightning.base.errors import InputError

from ..base.paths import ROOT, log

#: a Lightning checkpoint's entries only a resumed training reads
TRAINING_ONLY = ("optimizer_states", "lr_schedulers", "loops", "callbacks", "MixedPrecision", "native_amp_scaling_state")


def pack_checkpoint(src: Path, dest: Path) -> None:
    """``src`` without :data:`TRAINING_ONLY` entries, saved to ``dest`` (atomically); its weights checked equal."""
    from imls_lightning.base.atomic import atomic_write

    from ..base.config import load_checkpoint

    ckpt = load_checkpoint(src, what=str(src))
    packed = {k: v for k, v in ckpt.items() if k not in TRAINING_ONLY}
    atomic_write(dest, lambda f: torch.save(packed, f))
    again = load_checkpoint(dest, what=str(dest))["state_dict"]
    if set(again) != set(ckpt["state_dict"]) or not all(torch.equal(again[k], ckpt["state_dict"][k]) for k in again):
        dest.unlink(missing_ok=True)
        raise InputError(f"{dest}: its weights differ from {src}'s after packing")


def pack_networks(sources: Mapping[str, Path], dest: Path) -> dict[str, dict[str, str]]:
    """Each ``sources[key]`` checkpoint packed (:func:`pack_checkpoint`) into ``dest/<key>.ckpt``; returns
    ``{key: {"file": "<key>.ckpt", "sha256": <64 hex digits>}}``, as ``conf/row/<row>.yaml`` names them."""
    from ..base.config import file_hash

    dest.mkdir(parents=True, exist_ok=True)
    networks: dict[str, dict[str, str]] = {}
    for key, src in sources.items():
        if not src.is_file():
            raise InputError(f"checkpoints.{key}={src}: no such checkpoint file")
        out = dest / f"{key}.ckpt"
        pack_checkpoint(src, out)
        networks[key] = {"file": out.name, "sha256": file_hash(out, length=64)}
        log(f"[pack_row] {key}: {src} -> {out} ({out.stat().st_size / 2**20:.2f} MiB)")
    return networks


def pack_trained(sources: Mapping[str, Path], name: str, dest: Path, *, experiment: str | None = None) -> Path:
    """A row trained but not yet evaluated: its networks packed into ``dest`` (:func:`pack_networks`) and
    ``dest/trained.yaml`` (returned) naming them by SHA-256, with the experiment that trained them. A later session
    evaluates them without training again (``checkpoints.<key>=<dest>/<key>.ckpt`` in the row's evaluation command);
    ``pack_row evaluation=...`` then commits the point beside them."""
    from ..report import write_config

    if not sources:
        raise InputError("checkpoints: expected at least one network (checkpoints.<key>=<path>), got none")
    networks = pack_networks(sources, dest)
    record = {"name": name, "experiment": experiment, "evaluated": False, "networks": networks,
              # where they were trained, for the record (a run folder's name carries its settings hash)
              "trained_in": {k: f"{Path(src).parent.parent.name}/{Path(src).name}" for k, src in sources.items()}}
    out = dest / "trained.yaml"
    write_config(out, record, f"# row {name}: trained, not yet evaluated (python -m imls_lightning.pack_row checkpoints=...)\n")
    return out


def checked_networks(name: str, folder: Path, networks: Mapping[str, Mapping[str, Any]]) -> dict[str, Path]:
    """``{key: file}`` of a committed row's ``networks`` (``{key: {file, sha256}}``, as :func:`pack_networks` names
    them) under ``folder``, each file checked against its recorded SHA-256.

    Raises:
        InputError: a missing network file, or one whose bytes are not the recorded ones.
    """
    from ..base.config import file_hash

    files = {}
    for key, net in (networks or {}).items():
        path = folder / str(net["file"])
        if not path.is_file():
            raise InputError(f"row={name}: its network {key} ({path}) is missing; git checkout it, or retrain the row")
        got = file_hash(path, length=64)
        if got != str(net["sha256"]):
            raise InputError(f"row={name}: {path} has SHA-256 {got[:12]}..., the row records {str(net['sha256'])[:12]}...: "
                             "the file was altered")
        files[str(key)] = path
    return files


def trained_networks(folder: Path) -> dict[str, Path]:
    """The networks :func:`pack_trained` committed in ``folder`` (its ``trained.yaml``; for a row packed before that
    existed, its ``conf/row/<folder name>.yaml``, whose ``dir`` is the folder), each checked against its
    SHA-256: ``{key: file}`` with the keys of a pipeline's training stages (``recnn``, ``recnn_sparser``, ``iml``,
    ``ims``, ``blue_noise``, ``las``), so a pipeline evaluates them instead of training them again.

    Raises:
        InputError: no ``trained.yaml`` there, one that names no networks, or a missing or altered network.
    """
    folder = Path(folder)
    folder = folder if folder.is_absolute() else ROOT / folder
    record_path = folder / "trained.yaml"
    if not record_path.is_file():  # an evaluated row packed before trained.yaml existed: its conf/row record
        record_path = ROOT / "conf" / "row" / f"{folder.name}.yaml"
    record = OmegaConf.to_container(OmegaConf.load(record_path)) if record_path.is_file() else None
    if record_path.parent != folder and (not isinstance(record, dict)
                                         or (ROOT / str(record.get("dir", ""))).resolve() != folder.resolve()):
        raise InputError(f"trained={folder}: no trained.yaml there and no conf/row record of it (python -m "
                         "imls_lightning.pack_row name=<row> checkpoints.<key>=<ckpt> writes one)")
    if not isinstance(record, dict) or not isinstance(record.get("networks"), dict) or not record["networks"]:
        raise InputError(f"{record_path}: names no networks (expected networks: {{<key>: {{file, sha256}}}})")
    return checked_networks(str(record.get("name", folder.name)), folder, record["networks"])


def pack_row(evaluation: Path, name: str, dest: Path, *, data: str, trajectory_seed: int, settings: Sequence[str],
             views: int = 60, timed_views: int = 6, row_dir: Path | None = None) -> Path:
    """Pack the networks of the finished evaluation in ``evaluation`` (its ``config.yaml`` names them) into ``dest``,
    its point into ``dest/point``, and write ``conf/row/<name>.yaml`` (returned)."""
    from ..base.config import file_hash
    from ..report import atomic_write_text, write_config

    summary_path, config_path = evaluation / "summary.json", evaluation / "config.yaml"
    if not (summary_path.is_file() and config_path.is_file() and (evaluation / "report.md").is_file()):
        raise InputError(f"evaluation={evaluation}: expected a finished evaluation's folder (summary.json, config.yaml, report.md)")
    summary = json.loads(summary_path.read_text())
    config = OmegaConf.to_container(OmegaConf.load(config_path), resolve=True)
    sources = {key: Path(str(path)).expanduser() for key, path in (config.get("checkpoints") or {}).items() if path}
    for key, src in sources.items():
        if file_hash(src) != summary["checkpoints_sha256"].get(key):
            raise InputError(f"evaluation={evaluation}: its checkpoints.{key} ({src}) changed since it was evaluated")
    networks = pack_networks(sources, dest)
    point = dest / "point"
    point.mkdir(exist_ok=True)
    # the point's own record names the packed files as the evaluation names checkpoints (file_hash's 16 hex digits)
    packed_summary = {**summary, "checkpoints_sha256": {k: file_hash(dest / v["file"]) for k, v in networks.items()},
                      "packed_from": summary["checkpoints_sha256"]}
    atomic_write_text(point / "summary.json", json.dumps(packed_summary, indent=1))
    config["checkpoints"] = {k: str((dest / v["file"]).relative_to(ROOT)) if dest.is_relative_to(ROOT) else str(dest / v["file"])
                             for k, v in networks.items()}
    write_config(point / "config.yaml", config)
    row = {"name": name, "scene": summary["scene"], "recnn": summary["recnn"], "data": data,
           "dir": str(dest.relative_to(ROOT)) if dest.is_relative_to(ROOT) else str(dest), "point": "point",
           "trajectory_seed": int(trajectory_seed), "views": int(views), "timed_views": int(timed_views),
           "settings": list(settings), "networks": networks,
           # the point's record by content: an edited summary.json is refused like an altered network
           "point_sha256": file_hash(point / "summary.json", length=64)}
    out = (row_dir or ROOT / "conf" / "row") / f"{name}.yaml"
    header = (f"# row {name}: written by python -m imls_lightning.pack_row from {evaluation.name}; re-measure it with\n"
              f"# python -m imls_lightning.reproduce row={name} (networks under {row['dir']}, checked by SHA-256)\n")
    write_config(out, row, header)
    total = sum((dest / v["file"]).stat().st_size for v in networks.values())
    log(f"[pack_row] {name}: {len(networks)} networks, {total / 2**20:.1f} MiB in all -> {out}")
    return out
