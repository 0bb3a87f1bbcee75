"""Hydra override lines: the key a line sets, and the overrides of the IMS training an ORP job runs
on its IML (torch-free, used by the sweeper plugin). Values are quoted by
:func:`~imls_lightning.base.overrides.quote_override_value`, re-exported here."""
from __future__ import annotations

from typing import Sequence

from imls_lightning.base.overrides import quote_override_value

__all__ = ["quote_override_value", "override_key", "ims_overrides_for"]


def override_key(text: str) -> str:
    """The config key an override line sets (``+model.x=1`` -> ``model.x``; ``model=ims`` -> ``model``)."""
    head = text.split("=", 1)[0].lstrip("+~")
    return head.split("@", 1)[0]



def ims_overrides_for(task_overrides: Sequence[str], iml_checkpoint: str, extra: Sequence[str] = (),
                      recnn_checkpoint: str | None = None) -> list[str]:
    """Overrides that train IMS on ``iml_checkpoint`` with the job's scene/data/RecNN/trainer settings.

    Drops the IML's own ``model`` settings and the ORP flag; keeps everything else (scene, data,
    recnn.checkpoint, trainer limits, paths, ...), sets ``recnn.checkpoint=recnn_checkpoint`` when
    given (the RecNN an IMS checkpoint carries when the IML was standalone), then adds ``extra``.

    Example:
        >>> ims_overrides_for(["model=iml", "model.mean=0.1", "scene=tiny", "++orp_job={k:1}"], "/r/a.ckpt")
        ['scene=tiny', 'model=ims', 'iml.checkpoint=/r/a.ckpt']
    """
    drop = ("model", "orp_job", "iml.checkpoint") + (("recnn.checkpoint",) if recnn_checkpoint else ())
    keep = [o for o in task_overrides if not any(override_key(o) == d or override_key(o).startswith(d + ".") for d in drop)]
    out = keep + ["model=ims", f"iml.checkpoint={quote_override_value(str(iml_checkpoint))}"]
    if recnn_checkpoint:
        out.append(f"recnn.checkpoint={quote_override_value(str(recnn_checkpoint))}")
    return out + list(extra)
