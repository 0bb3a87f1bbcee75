"""imls-lightning: Importance Mask Learning (IML) and Synthesis (IMS) for RecNN volume rendering.

The small public API, importable from the package itself::

    from imls_lightning import IMLSRenderer
    renderer = IMLSRenderer.from_checkpoints("ims.ckpt")   # IMS + IML decoder + RecNN + scene
    image = renderer.render(view)                          # view: 9 floats (eye, lookAt, up)
    image, timings = timed(renderer).render(view)          # the same, timed by stage (imls_lightning.evaluation.timing)

Every name in :data:`__all__` lives in one home module (see :data:`HOMES`) and is imported from
there on first use (PEP 562 module ``__getattr__``), so ``import imls_lightning`` stays cheap: it
loads no torch, and no module of the package imports this one, so it can take part in no cycle.
"""
from __future__ import annotations

import importlib
from typing import Any

__version__ = "0.1.0"

#: public name -> the module it lives in (its one home)
HOMES: dict[str, str] = {
    # inference methods (imls_lightning.evaluation measures these) and their options
    "IMLSRenderer": "imls_lightning.inference.pipeline",
    "FullRayCast": "imls_lightning.inference.pipeline",
    "RecNNAlone": "imls_lightning.inference.pipeline",
    "IMLPlusRecNN": "imls_lightning.inference.pipeline",
    "LASMethod": "imls_lightning.inference.pipeline",
    "Method": "imls_lightning.inference.pipeline",
    "NetOptions": "imls_lightning.inference.options",
    "OperatingPoint": "imls_lightning.core.operating_point",
    "Bands": "imls_lightning.core.operating_point",
    "time_method": "imls_lightning.evaluation.timing",
    "time_methods": "imls_lightning.evaluation.timing",
    "timed": "imls_lightning.evaluation.timing",
    "pick_device": "imls_lightning.inference.options",
    "AdaptiveIMLSRenderer": "imls_lightning.adaptive.renderer",
    "ExportedIMLSRenderer": "imls_lightning.inference.export",
    "export_renderer": "imls_lightning.inference.export",
    # networks
    "IMLNet": "imls_lightning.models.iml",
    "IMSGenerator": "imls_lightning.models.ims",
    "IMSDiscriminator": "imls_lightning.models.ims",
    "IMSMaskHead": "imls_lightning.models.ims",
    "EnhanceNet": "imls_lightning.models.enhancenet",
    "FoVolNet": "imls_lightning.models.fovolnet",
    "UNet": "imls_lightning.models.unet",
    # LightningModules and checkpoints
    "IMLTask": "imls_lightning.tasks.iml",
    "IMSTask": "imls_lightning.tasks.ims",
    "RecNNTask": "imls_lightning.tasks.recnn",
    "LASTask": "imls_lightning.tasks.las",
    "load_task": "imls_lightning.inference.checkpoints",
    "load_ims_nets": "imls_lightning.inference.checkpoints",
    "load_product": "imls_lightning.inference.checkpoints",
    # sampling pattern, compaction, importance
    "SamplingPattern": "imls_lightning.core.patterns",
    "build_pattern": "imls_lightning.core.patterns",
    "compact": "imls_lightning.core.compaction",
    "decompact": "imls_lightning.core.compaction",
    "normalize_importance": "imls_lightning.core.importance",
    # the ORP search (torch-free)
    "ORPSearch": "imls_lightning.orp.search",
}

__all__ = sorted(HOMES)


def __getattr__(name: str) -> Any:
    """Import a public name from its home module on first use (and keep it here)."""
    home = HOMES.get(name)
    if home is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(home), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
