"""The browser viewer: ``python -m imls_lightning.web ims_checkpoint=<IMS .ckpt>`` (``make web``).

* :mod:`.session`: :class:`ViewerSession`, the camera, method, share of the C-Image and frames (no web code).
* :mod:`.app`: :class:`WebViewer`, the trame page (needs the ``web`` extra: ``pip install -e '.[web]'``).
* :mod:`.__main__`: the Hydra entry point.
"""
from .session import METHODS, Frame, ViewerSession, png_data_url

__all__ = ["METHODS", "Frame", "ViewerSession", "png_data_url"]
