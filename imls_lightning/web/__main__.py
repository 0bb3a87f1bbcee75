"""``python -m imls_lightning.web``: serve the browser viewer (conf/web.yaml)."""
from __future__ import annotations

from pathlib import Path

import hydra
from omegaconf import DictConfig, OmegaConf

from data_gen.errors import InputError, checked_command_line, cli_errors

from ..inference.pipeline import NetOptions

LOCAL_HOSTS = ("127.0.0.1", "localhost", "::1")


def checkpoints(cfg: DictConfig) -> tuple[str, str | None, str | None]:
    """``(ims, recnn, las)`` checkpoints: the settings, or those of ``from_report`` (an evaluation's
    ``report.md``, whose ``config.yaml`` beside it names them); explicit settings win."""
    ims, recnn, las = cfg.ims_checkpoint, cfg.recnn_checkpoint, cfg.las_checkpoint
    if cfg.get("from_report"):
        conf = Path(str(cfg.from_report)).parent / "config.yaml"
        try:
            ck = OmegaConf.load(conf).checkpoints
        except Exception:
            raise InputError(f"from_report={cfg.from_report}: expected an evaluation's report.md with its config.yaml beside it") from None
        ims, recnn, las = ims or ck.get("ims"), recnn or ck.get("recnn"), las or ck.get("las")
    if not ims:
        raise InputError("ims_checkpoint: expected an IMS .ckpt (or from_report=<an evaluation's report.md>)")
    return str(ims), (str(recnn) if recnn else None), (str(las) if las else None)


def serve(cfg: DictConfig, *, exec_mode: str = "main"):
    """Start the page on ``cfg.host:cfg.port``; the checkpoints load once the page is up."""
    try:
        from trame.app import get_server
    except ImportError:
        raise InputError("the browser viewer needs trame: pip install -e '.[web]' (trame, trame-vuetify)") from None
    import torch

    from .app import WebViewer, log
    from .session import ViewerSession

    if cfg.threads is not None:
        torch.set_num_threads(int(cfg.threads))
    host = str(cfg.host)
    if host not in LOCAL_HOSTS:
        log(f"warning: host={host}: the viewer is reachable from other machines, with no authentication")
    opts = NetOptions(**{k: cfg.options[k] for k in ("device", "half", "channels_last", "compile")})

    ims, recnn, las = checkpoints(cfg)

    def load() -> ViewerSession:
        return ViewerSession.from_checkpoints(ims, recnn, las, cfg.adaptive_predictor, opts=opts,
                                              azimuth=float(cfg.azimuth), elevation=float(cfg.elevation),
                                              distance=cfg.distance, method=str(cfg.method), mean=cfg.get("mean"))

    server = get_server(name="imls-web", client_type="vue3")
    WebViewer(server, load)
    log(f"serving http://{host}:{int(cfg.port)}/ (Ctrl+C stops it)")
    return server.start(host=host, port=int(cfg.port), open_browser=bool(cfg.open_browser), timeout=int(cfg.timeout),
                        show_connection_info=True, exec_mode=exec_mode)


@checked_command_line(Path(__file__).resolve().parents[2] / "conf")
@hydra.main(version_base="1.3", config_path="../../conf", config_name="web")
@cli_errors
def main(cfg: DictConfig) -> None:
    serve(cfg)


if __name__ == "__main__":
    main()
