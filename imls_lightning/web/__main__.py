"""``python -m imls_lightning.web``: serve the browser viewer (conf/web.yaml)."""
from __future__ import annotations

from pathlib import Path

import hydra
from omegaconf import DictConfig, OmegaConf

from imls_lightning.base.errors import InputError, checked_command_line, cli_errors
from imls_lightning.base.validate import check_integer

from ..inference.operating_point import share_setting
from ..inference.pipeline import NetOptions

LOCAL_HOSTS = ("127.0.0.1", "localhost", "::1")


def checkpoints(cfg: DictConfig) -> tuple[str, str | None, str | None]:
    """``(ims, recnn, las)`` checkpoints: the settings, or those of ``from_report`` (an evaluation's
    ``report.md``, whose ``config.yaml`` beside it names them); explicit settings win. Each file is checked to be
    there and intact (:func:`~imls_lightning.base.config.checkpoint_problem`), and so is ``adaptive_predictor``, before
    the page is served: a missing or damaged one is a one-line :class:`InputError` naming the setting it came from
    (a checkpoint of the wrong kind shows its message in the page, which loads them)."""
    from ..base.config import checkpoint_problem

    given = {"ims": cfg.ims_checkpoint, "recnn": cfg.recnn_checkpoint, "las": cfg.las_checkpoint}
    keys = {k: f"{k}_checkpoint" for k in given}
    if cfg.get("from_report"):
        report = Path(str(cfg.from_report)).expanduser()
        conf = report.parent / "config.yaml"
        if not report.is_file():
            raise InputError(f"from_report={cfg.from_report}: no such file; expected an evaluation's report.md (the demo "
                             "prints its path last)")
        try:
            ck = OmegaConf.load(conf).checkpoints
        except Exception:
            raise InputError(f"from_report={cfg.from_report}: expected an evaluation's report.md with its config.yaml beside it") from None
        for k in given:
            if not given[k] and ck.get(k):
                given[k], keys[k] = ck.get(k), f"from_report={cfg.from_report}: its checkpoints.{k}"
    if not given["ims"]:
        raise InputError("ims_checkpoint: expected an IMS .ckpt (or from_report=<an evaluation's report.md>)")
    for k, path in given.items():
        problem = None if not path else checkpoint_problem(str(path))
        if problem is not None:
            where = f"{keys[k]}={path}" if keys[k].endswith("_checkpoint") else f"{keys[k]} ({path})"
            raise InputError(f"{where}: {problem}")
    predictor = cfg.get("adaptive_predictor")
    if predictor and not Path(str(predictor)).expanduser().is_file():
        raise InputError(f"adaptive_predictor={predictor}: file not found (python -m imls_lightning.adaptive writes "
                         "mean_predictor.pt)")
    ims, recnn, las = given["ims"], given["recnn"], given["las"]
    return str(ims), (str(recnn) if recnn else None), (str(las) if las else None)


def check_port(host: str, port: int) -> None:
    """Refuse, before anything says "serving", an address the server cannot listen on: a port another process holds,
    a port this user may not open, a host that is not this machine's. Port 0 (a free one) is always fine.

    Raises:
        InputError: one line naming ``port`` (or ``host``).
    """
    import errno
    import socket

    try:
        family, kind, proto, _, addr = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)[0]
    except (socket.gaierror, UnicodeError) as err:
        raise InputError(f"host={host}: not an address of this machine ({getattr(err, 'strerror', None) or err})") from None
    with socket.socket(family, kind, proto) as probe:
        probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # as the server does: a closed one's TIME_WAIT is fine
        try:
            probe.bind(addr)
        except OSError as err:
            if err.errno == errno.EADDRINUSE:
                raise InputError(f"port={port}: already in use on {host} (another server, or a viewer still running); "
                                 "pass another port, or port=0 for a free one") from None
            if err.errno == errno.EACCES:
                raise InputError(f"port={port}: this user may not open it (ports below 1024 need privileges); pass "
                                 "another port, or port=0 for a free one") from None
            raise InputError(f"host={host} port={port}: cannot listen there ({err.strerror or type(err).__name__})") from None


def serve(cfg: DictConfig, *, exec_mode: str = "main"):
    """Start the page on ``cfg.host:cfg.port``; the checkpoints load once the page is up."""
    try:
        from trame.app import get_server
    except ImportError:
        raise InputError("the browser viewer needs trame: pip install -e '.[web]' (trame, trame-vuetify)") from None
    import torch

    from .app import WebViewer, log
    from .session import ViewerSession

    host, port = str(cfg.host), check_integer(cfg.port, "port", 0, 65535)
    timeout = check_integer(cfg.timeout, "timeout", 0)
    ims, recnn, las = checkpoints(cfg)  # the files, the report and the port first: nothing says "serving" before
    check_port(host, port)
    if cfg.threads is not None:
        torch.set_num_threads(check_integer(cfg.threads, "threads", 1))
    if host not in LOCAL_HOSTS:
        log(f"warning: host={host}: the viewer is reachable from other machines, with no authentication")
    opts = NetOptions(**{k: cfg.options[k] for k in ("device", "half", "channels_last", "compile")})

    value, key = share_setting(cfg)  # share (mean: its older name)

    def load() -> ViewerSession:
        return ViewerSession.from_checkpoints(ims, recnn, las, cfg.adaptive_predictor, opts=opts,
                                              azimuth=float(cfg.azimuth), elevation=float(cfg.elevation),
                                              distance=cfg.distance, method=str(cfg.method), **{key: value})

    server = get_server(name="imls-web", client_type="vue3")
    WebViewer(server, load)
    log(f"serving http://{host}:{port}/ (Ctrl+C stops it)")
    try:
        return server.start(host=host, port=port, open_browser=bool(cfg.open_browser), timeout=timeout,
                            show_connection_info=True, exec_mode=exec_mode)
    except OSError as err:  # the port taken between the check and now
        raise InputError(f"port={port}: cannot serve on {host} ({err.strerror or type(err).__name__})") from None


@checked_command_line(Path(__file__).resolve().parents[2] / "conf", "web")
@hydra.main(version_base="1.3", config_path="../../conf", config_name="web")
@cli_errors
def main(cfg: DictConfig) -> None:
    serve(cfg)


if __name__ == "__main__":
    main()
