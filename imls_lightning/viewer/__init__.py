"""Interactive viewer: orbit the volume and compare the IML/S + RecNN frame with the ray cast, live.

``python -m imls_lightning.viewer ims_checkpoint=PATH [recnn_checkpoint=PATH] [screenshot=out.png]
[azimuth=30] [elevation=20] [distance=null] [mask=true] [share=null]``

A matplotlib window with two image panels side by side, **IML/S + RecNN** (the product:
:class:`~imls_lightning.inference.pipeline.IMLSRenderer`) and **ray cast (ground truth)** (the same scene
renderer's full render of every FR pixel), an optional small panel with the importance mask (the FR
pixels the IML/S frame really ray-cast), and a latency panel: one bar per stage of
``IMLSRenderer.run(view)`` (``importance``, ``selective_render``, ``decoder``, ``recnn``, ``total``)
and the full ray cast's time, in milliseconds, with the frame's IPR (rendered / FR pixels), its PSNR
against the ray cast and the speed-up. Latencies are those of the frame on screen (one run, not a
median: :mod:`imls_lightning.evaluation` measures medians).

The IMS checkpoint alone is enough: it records the scene and renderer it was trained on (see
:meth:`IMLSRenderer.from_checkpoints`); ``recnn_checkpoint=`` swaps in another RecNN. The frame is
rendered at the operating point the evaluation recorded beside the checkpoint (``<ims.ckpt>.orp.json``),
else at the trained share; ``share=`` (a number, or ``trained``; ``mean=``: its older name) overrides it; the
panel's title shows the share.

Controls
    ==================  ==============================================================
    left-drag           orbit the camera around the volume centre (azimuth/elevation)
    scroll wheel        zoom (camera distance, clamped to ``scene.camera_distance``)
    arrow keys          orbit by 10 degrees (like a drag in that direction)
    ``r``               reset the camera to the start view
    ``m``               show/hide the importance mask panel
    ``q``               quit
    ==================  ==============================================================

Responsiveness: rendering runs in the GUI thread, the IML/S frame first and the ray cast after it.
While dragging only the IML/S frame is rendered (motion events that arrive during a render are
coalesced into one render of the latest camera); the ray cast, the PSNR and the speed-up follow on
mouse release (the ray-cast panel says "release to update" meanwhile). A scroll or a key press
renders the IML/S frame, shows it, then ray-casts.

Camera: the z axis is the polar axis (as in :func:`data_gen.views.exploration_trajectory`): the eye
sits at ``distance * (cos(el) cos(az), cos(el) sin(az), sin(el))`` around the look-at point (the
volume centre, the origin), ``up`` is +z made orthogonal to the view direction; elevation is kept
within +-89 degrees so that ``up`` never becomes parallel to the view direction.

``screenshot=out.png`` renders headless (Agg backend), writes the PNG atomically (temporary name +
rename), prints its path as the last stdout line and exits; this is how the tests and the README
picture are made. Without a display and without ``screenshot=`` the command stops with a one-line
error.

The package: :mod:`.window` holds :class:`Viewer` (the figure, its rendering and its events),
:mod:`.run` the command's body :func:`viewer` (checks, the renderer from the checkpoints, a screenshot
or the window), and ``__main__`` the Hydra entry point (``conf/viewer.yaml``).

Example:
    python -m imls_lightning.viewer ims_checkpoint=runs/ims-.../checkpoints/last.ckpt
    python -m imls_lightning.viewer ims_checkpoint=ims.ckpt screenshot=docs/viewer.png azimuth=40 elevation=25

    >>> r = IMLSRenderer.from_checkpoints("ims.ckpt")                  # doctest: +SKIP
    >>> v = Viewer(r, azimuth=30, elevation=20)                          # headless (Agg) figure  # doctest: +SKIP
    >>> v.orbit(15, 0); v.update()                                       # doctest: +SKIP
    >>> print(v.latency_text())                                          # doctest: +SKIP
    >>> v.save_screenshot("viewer.png")                                  # doctest: +SKIP
"""
from ..inference.camera import MAX_ELEVATION, frame_psnr, orbit_view  # their old home re-exports them
from .run import check_writable, viewer
from .window import IMLS_STAGES, RAY_CAST, Viewer

__all__ = ["IMLS_STAGES", "RAY_CAST", "MAX_ELEVATION", "orbit_view", "frame_psnr", "Viewer", "viewer", "check_writable"]
