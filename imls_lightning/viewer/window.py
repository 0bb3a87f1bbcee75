"""The viewer's figure (:class:`Viewer`): IML/S + RecNN beside the ray cast, the importance mask, the
latency bars and the stats, its rendering and its mouse and key events (see :mod:`imls_lightning.viewer`)."""
from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Any, Sequence

import numpy as np
import torch

from imls_lightning.base.errors import InputError, finite_number

from ..inference.camera import DEFAULT_DISTANCE_RANGE, OrbitCamera, frame_psnr, orbit_view
from ..evaluation.timing import timed
from ..inference.pipeline import FullRayCast, IMLSRenderer, RenderResult

__all__ = ["IMLS_STAGES", "RAY_CAST", "Viewer"]

#: the stages of ``IMLSRenderer.run`` shown as bars (in pipeline order), then the full ray cast
IMLS_STAGES = ("importance", "selective_render", "decoder", "recnn", "total")
RAY_CAST = "ray cast (full)"
ORBIT_STEP = 10.0              # degrees per arrow key
DRAG_DEGREES_PER_PIXEL = 0.4


class _Drag:
    def __init__(self, x: float, y: float):
        self.x, self.y, self.moved = x, y, False


class Viewer(OrbitCamera):
    """The viewer window (or a headless Agg figure): IML/S + RecNN beside the ray cast, with latency.

    Args:
        renderer: an :class:`IMLSRenderer`; its scene renderer also makes the ray cast.
        azimuth, elevation, distance: start camera (degrees, degrees, normalized units); ``distance``
            ``None`` = the middle of ``scene.camera_distance``; it must lie in that range.
        show_mask: show the importance-mask panel.
        interactive: ``True``: a pyplot window (call :meth:`show`); ``False``: an Agg figure with no
            window (tests, screenshots); events can still be fed to the handlers.
        figsize, dpi: figure size in inches and dots per inch (the screenshot is ``figsize * dpi`` pixels).
        warmup: untimed renders of the start view before the first shown frame (JIT compilation,
            first-call allocations), so the first latencies on screen are representative.

    Attributes:
        frames: number of IML/S frames rendered (shown); ``ray_casts``: number of full ray casts.
        imls, truth: the last :class:`RenderResult` of each; ``imls_view``, ``truth_view``: the views
            they show (``truth`` may be of an older view while a drag is under way: see :attr:`truth_stale`).
    """

    def __init__(self, renderer: IMLSRenderer, *, azimuth: float = 30.0, elevation: float = 20.0,
                 distance: float | None = None, show_mask: bool = True, interactive: bool = False,
                 figsize: Sequence[float] = (12.0, 6.5), dpi: float = 100.0, warmup: int = 1):
        self.renderer = timed(renderer)  # the latency bars: each stage timed from outside the renderer
        self.ray_caster = timed(FullRayCast(renderer.renderer, renderer.fr_size, renderer.opts))
        scene = getattr(renderer.renderer, "scene", None)
        lo, hi = (float(c) for c in getattr(scene, "camera_distance", DEFAULT_DISTANCE_RANGE))
        self.distance_range = (lo, hi)
        self.scene_name = getattr(scene, "name", "?")
        dist = 0.5 * (lo + hi) if distance is None else finite_number(distance, "distance", "a finite number")
        if not (lo - 1e-9 <= dist <= hi + 1e-9):
            raise InputError(f"distance={distance}: expected a camera distance in scene.camera_distance=[{lo:g}, {hi:g}]")
        orbit_view(azimuth, elevation, dist)  # validates the angles (one-line InputError)
        self.home = (finite_number(azimuth, "azimuth", "a finite number"), finite_number(elevation, "elevation", "a finite number"), dist)
        self.azimuth, self.elevation, self.distance = self.home
        if isinstance(warmup, bool) or not isinstance(warmup, (int, np.integer)) or warmup < 0:
            raise InputError(f"warmup={warmup}: expected an integer >= 0")
        self.show_mask = bool(show_mask)
        self.interactive = bool(interactive)
        self.frames = 0
        self.ray_casts = 0
        self.imls: RenderResult | None = None
        self.truth: RenderResult | None = None
        self.imls_view: np.ndarray | None = None
        self.truth_view: np.ndarray | None = None
        self.psnr: float | None = None
        self._drag: _Drag | None = None
        self._pending_full = False
        self._timer = None
        self._build_figure(tuple(float(f) for f in figsize), float(dpi))
        with torch.inference_mode():
            for _ in range(int(warmup)):
                v = self.view()
                self.renderer.run(v)
                self.ray_caster.run(v)
        self.update(full=True)

    def toggle_mask(self) -> None:
        """Show/hide the importance mask panel."""
        self.show_mask = not self.show_mask
        self._layout()
        self._redraw()

    # -- rendering -------------------------------------------------------------------------------
    def update(self, full: bool = True) -> None:
        """Render the IML/S frame of the current view and show it; with ``full`` also the ray cast
        (after the IML/S frame is on screen), the PSNR and the speed-up."""
        view = self.view()
        with torch.inference_mode():
            self.imls = self.renderer.run(view)
        self.imls_view = view
        self.frames += 1
        self._show_imls()
        if full:
            if self.interactive:  # the IML/S frame appears before the (slower) ray cast starts
                self._redraw(now=True)
            with torch.inference_mode():
                self.truth = self.ray_caster.run(view)
            self.truth_view = view
            self.ray_casts += 1
            self.psnr = frame_psnr(self.imls.image, self.truth.image)
            self._artists["truth"].set_data(self.truth.image)
        self._show_stats()
        self._redraw()

    @property
    def truth_stale(self) -> bool:
        """Whether the ray-cast panel shows an older view than the IML/S panel (during a drag)."""
        return self.truth_view is None or not np.array_equal(self.truth_view, self.view())

    def latency_text(self) -> str:
        """One line per stage: ``name  12.3 ms`` (IML/S stages, total, the full ray cast), then IPR and PSNR."""
        t = self.imls.timings if self.imls is not None else {}
        lines = [f"{k:<17s}{1e3 * t.get(k, math.nan):9.1f} ms" for k in IMLS_STAGES]
        full = self.truth.timings["total"] if self.truth is not None else math.nan
        lines.append(f"{RAY_CAST:<17s}{1e3 * full:9.1f} ms" + ("  (previous view)" if self.truth_stale else ""))
        lines.extend(self._stats_lines())
        return "\n".join(lines)

    def _stats_lines(self) -> list[str]:
        info = self.imls.info if self.imls is not None else {}
        m = self.renderer.fr_size
        out = [f"IPR {info.get('ipr', math.nan):.3f}  ({info.get('rendered_pixels', 0):,} / {m * m:,} px ray-cast)"]
        if self.psnr is None or self.truth_stale:
            out.append("PSNR vs ray cast  -  (release to update)")
        else:
            out.append(f"PSNR vs ray cast  {self.psnr:.2f} dB")
            total = self.imls.timings.get("total", math.nan)
            if total > 0:
                out.append(f"speed-up vs ray cast  x{self.truth.timings['total'] / total:.2f}")
        out.append(f"camera  az {self.azimuth:.0f} deg  el {self.elevation:.0f} deg  dist {self.distance:.2f}")
        return out

    # -- events ------------------------------------------------------------------------------------
    def on_press(self, event) -> None:
        """Left button down: start an orbit drag."""
        if getattr(event, "button", None) == 1 and event.x is not None and event.y is not None:
            self._drag = _Drag(float(event.x), float(event.y))

    def on_motion(self, event) -> None:
        """Drag: orbit by the mouse motion and render the IML/S frame only."""
        d = self._drag
        if d is None or event.x is None or event.y is None:
            return
        dx, dy = float(event.x) - d.x, float(event.y) - d.y
        if dx == 0 and dy == 0:
            return
        d.x, d.y, d.moved = float(event.x), float(event.y), True
        # grab-and-turn: the volume follows the mouse, so the camera moves the other way
        self.orbit(-DRAG_DEGREES_PER_PIXEL * dx, -DRAG_DEGREES_PER_PIXEL * dy)
        self._request(full=False)

    def on_release(self, event) -> None:
        """Left button up: end the drag and ray-cast the view it stopped at."""
        d, self._drag = self._drag, None
        if d is not None and (d.moved or self.truth_stale):
            self._request(full=True)

    def on_scroll(self, event) -> None:
        """Scroll: zoom in (up) or out (down)."""
        step = getattr(event, "step", 0) or (1 if getattr(event, "button", None) == "up" else -1)
        self.zoom(step)
        self._request(full=True)

    def on_key(self, event) -> None:
        """``r`` reset, ``m`` mask panel, ``q`` quit, arrows orbit."""
        key = getattr(event, "key", None)
        arrows = {"left": (ORBIT_STEP, 0.0), "right": (-ORBIT_STEP, 0.0), "up": (0.0, -ORBIT_STEP), "down": (0.0, ORBIT_STEP)}
        if key in arrows:
            self.orbit(*arrows[key])
            self._request(full=True)
        elif key == "r":
            self.reset()
            self._request(full=True)
        elif key == "m":
            self.toggle_mask()
        elif key == "q":
            self.close()

    def _request(self, full: bool) -> None:
        """Render now (headless), or once the queued events are handled (interactive: coalesces a burst
        of motion events into one render of the latest camera)."""
        self._pending_full = self._pending_full or full
        if self._timer is None:
            self._flush()
        else:
            self._timer.start()

    def _flush(self) -> None:
        full, self._pending_full = self._pending_full, False
        self.update(full=full)

    # -- figure --------------------------------------------------------------------------------------
    def _build_figure(self, figsize: tuple[float, ...], dpi: float) -> None:
        if len(figsize) != 2 or not all(math.isfinite(f) and f > 0 for f in figsize):
            raise InputError(f"figsize={list(figsize)}: expected [width, height] in inches, both > 0")
        if not (math.isfinite(dpi) and dpi > 0):
            raise InputError(f"dpi={dpi}: expected a positive number")
        if self.interactive:
            import matplotlib.pyplot as plt

            with plt.rc_context({"toolbar": "None"}):  # no pan/zoom mode stealing the left drag
                fig = plt.figure(figsize=figsize, dpi=dpi)
            manager = fig.canvas.manager
            if manager is not None and getattr(manager, "key_press_handler_id", None) is not None:
                # matplotlib's default keys (r = home, left/right = back/forward, q = quit) would clash
                fig.canvas.mpl_disconnect(manager.key_press_handler_id)
            try:
                manager.set_window_title(f"IML/S viewer - {self.scene_name}")
            except Exception:  # window titles are cosmetic
                pass
        else:
            from matplotlib.backends.backend_agg import FigureCanvasAgg
            from matplotlib.figure import Figure

            fig = Figure(figsize=figsize, dpi=dpi)
            FigureCanvasAgg(fig)
        self.fig = fig
        m = self.renderer.fr_size
        blank = np.zeros((m, m, 3), np.uint8)
        self.axes: dict[str, Any] = {}
        self._artists: dict[str, Any] = {}
        share = getattr(self.renderer, "mean", None)  # the renderer's share of C (the paper's mean value u)
        u = "" if share is None else f" (share of C {float(share):.2f})"
        if getattr(self.renderer, "by_distance", None) is not None:
            u = " (share by camera distance)"
        titles = {"imls": "IML/S + RecNN" + u, "truth": "ray cast (ground truth)", "mask": "importance mask\n(FR pixels ray-cast)"}
        for name in ("imls", "truth", "mask"):
            ax = fig.add_axes((0, 0, 1, 1))
            ax.set_xticks([]), ax.set_yticks([])
            ax.set_title(titles[name], fontsize=12 if name != "mask" else 9)
            img = blank[..., 0] if name == "mask" else blank
            self._artists[name] = ax.imshow(img, interpolation="nearest", cmap="gray" if name == "mask" else None,
                                            vmin=0, vmax=1 if name == "mask" else None)
            self.axes[name] = ax
        lat = fig.add_axes((0, 0, 1, 1))
        labels = [*IMLS_STAGES, RAY_CAST]
        colours = ["#4c72b0"] * 4 + ["#1f3b73", "#c44e52"]
        self._bars = lat.barh(range(len(labels)), [0.0] * len(labels), color=colours)
        lat.set_yticks(range(len(labels)), labels, fontsize=9)
        lat.invert_yaxis()
        lat.set_xlabel("latency of this frame [ms]", fontsize=9)
        lat.tick_params(axis="x", labelsize=8)
        lat.grid(axis="x", alpha=0.3)
        self._bar_labels = [lat.text(0, i, "", va="center", fontsize=8) for i in range(len(labels))]
        self.axes["latency"] = lat
        txt = fig.add_axes((0, 0, 1, 1))
        txt.axis("off")
        self._stats = txt.text(0.0, 1.0, "", va="top", ha="left", family="monospace", fontsize=9, transform=txt.transAxes)
        self.axes["stats"] = txt
        fig.suptitle(f"scene {self.scene_name}  (m = {m})    drag: orbit   scroll: zoom   arrows: orbit   "
                     "r: reset   m: mask   q: quit", fontsize=10, y=0.99)
        self._layout()
        for name, handler in (("button_press_event", self.on_press), ("motion_notify_event", self.on_motion),
                              ("button_release_event", self.on_release), ("scroll_event", self.on_scroll),
                              ("key_press_event", self.on_key)):
            fig.canvas.mpl_connect(name, handler)

    def _layout(self) -> None:
        top, height = 0.31, 0.57
        if self.show_mask:
            self.axes["imls"].set_position((0.01, top, 0.38, height))
            self.axes["truth"].set_position((0.40, top, 0.38, height))
            self.axes["mask"].set_position((0.80, top + 0.12, 0.18, height - 0.24))
        else:
            self.axes["imls"].set_position((0.05, top, 0.44, height))
            self.axes["truth"].set_position((0.51, top, 0.44, height))
        self.axes["mask"].set_visible(self.show_mask)
        self.axes["latency"].set_position((0.15, 0.11, 0.40, 0.15))
        self.axes["stats"].set_position((0.60, 0.04, 0.39, 0.22))

    def _show_imls(self) -> None:
        from ..core.patterns import c_pixels_to_fr

        self._artists["imls"].set_data(self.imls.image)
        im = self.imls.info.get("im")
        if im is not None:
            m = self.renderer.fr_size
            mask = np.zeros(m * m, np.float32)
            mask[c_pixels_to_fr(self.renderer.pattern, im).numpy()] = 1.0
            self._artists["mask"].set_data(mask.reshape(m, m))

    def _show_stats(self) -> None:
        t = self.imls.timings
        ms = [1e3 * t.get(k, 0.0) for k in IMLS_STAGES]
        ms.append(1e3 * self.truth.timings["total"] if self.truth is not None else 0.0)
        stale = self.truth_stale
        for i, (bar, label, v) in enumerate(zip(self._bars, self._bar_labels, ms)):
            bar.set_width(v)
            last = i == len(ms) - 1
            bar.set_alpha(0.35 if last and stale else 1.0)
            label.set_position((v, i))
            label.set_text(f" {v:.1f} ms" + (" (prev. view)" if last and stale else ""))
        self.axes["latency"].set_xlim(0, max(max(ms), 1e-3) * 1.45)
        self.axes["truth"].set_title("ray cast (ground truth)" + ("\n(release to update)" if stale else ""), fontsize=12)
        self._stats.set_text("\n".join(self._stats_lines()))

    def _redraw(self, now: bool = False) -> None:
        canvas = self.fig.canvas
        if self.interactive:
            if now:
                canvas.draw()
                canvas.flush_events()
            else:
                canvas.draw_idle()

    # -- output ------------------------------------------------------------------------------------
    def panel_box(self, name: str) -> tuple[int, int, int, int]:
        """Pixel box ``(row0, row1, col0, col1)`` of a panel (``imls``, ``truth``, ``mask``) in the
        saved image (row 0 at the top), the image area only."""
        if name not in ("imls", "truth", "mask"):
            raise InputError(f"name={name!r}: expected 'imls', 'truth' or 'mask'")
        self.fig.canvas.draw()
        bb = self.axes[name].get_window_extent()
        h = int(round(self.fig.get_figheight() * self.fig.dpi))
        return int(math.ceil(h - bb.y1)), int(h - bb.y0), int(math.ceil(bb.x0)), int(bb.x1)

    def save_screenshot(self, path: str | os.PathLike) -> Path:
        """Write the figure as a PNG (``figsize * dpi`` pixels) atomically; returns the path."""
        out = Path(str(path)).expanduser()
        if out.suffix.lower() != ".png":
            raise InputError(f"screenshot={path}: expected a .png path")
        if out.is_dir():
            raise InputError(f"screenshot={path}: is a directory, expected a .png file path")
        from imls_lightning.base.atomic import atomic_write

        return atomic_write(out, lambda f: self.fig.savefig(f, format="png", dpi=self.fig.dpi), unique=True)

    def show(self) -> None:
        """Open the window and run the GUI loop until it is closed (``q``)."""
        if not self.interactive:
            raise InputError("interactive=False: this viewer has no window; use save_screenshot(path)")
        import matplotlib.pyplot as plt

        self._timer = self.fig.canvas.new_timer(interval=1)
        self._timer.single_shot = True
        self._timer.add_callback(self._flush)
        plt.show()

    def close(self) -> None:
        """Close the window (interactive) or release the figure."""
        if self.interactive:
            import matplotlib.pyplot as plt

            plt.close(self.fig)
