"""Hydra override lines: a value quoted for the override grammar, the key a line sets, and the
overrides of the IMS training an ORP job runs on its IML (torch-free, used by the sweeper plugin)."""
from __future__ import annotations

import re
from typing import Any, Mapping, Sequence


def quote_override_value(value: Any) -> str:
    """A value written so that Hydra's override grammar reads it back unchanged.

    Strings are single-quoted (``'`` escaped, and backslashes only where they precede a quote), lists/dicts recursively, ``None`` is
    ``null``; numbers and booleans as such.

    Example:
        >>> quote_override_value({"a": [1, "x=y"], "b": None, "c": True})
        "{a:[1,'x=y'],b:null,c:true}"
    """
    if value is None:
        return "null"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (int, float)):
        return repr(value)
    if isinstance(value, Mapping):
        return "{" + ",".join(f"{k}:{quote_override_value(v)}" for k, v in value.items()) + "}"
    if isinstance(value, (list, tuple)):
        return "[" + ",".join(quote_override_value(v) for v in value) + "]"
    # Hydra reads a backslash literally unless a run of them precedes a quote (an escaped one, or the
    # closing one): only those runs are doubled, then the quotes escaped
    s = re.sub(r"(\\+)(?='|$)", lambda m: m.group(1) * 2, str(value))
    return "'" + s.replace("'", "\\'") + "'"


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
        ['scene=tiny', 'model=ims', "iml.checkpoint='/r/a.ckpt'"]
    """
    drop = ("model", "orp_job", "iml.checkpoint") + (("recnn.checkpoint",) if recnn_checkpoint else ())
    keep = [o for o in task_overrides if not any(override_key(o) == d or override_key(o).startswith(d + ".") for d in drop)]
    out = keep + ["model=ims", f"iml.checkpoint={quote_override_value(str(iml_checkpoint))}"]
    if recnn_checkpoint:
        out.append(f"recnn.checkpoint={quote_override_value(str(recnn_checkpoint))}")
    return out + list(extra)
