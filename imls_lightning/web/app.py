"""The browser viewer's page (trame, Vue 3 + Vuetify): drag to orbit, scroll to zoom, pick the
method, move the share-of-C slider; the method's image, its mask and its error side by side, with
the stage latencies, the share of pixels ray-cast, the PSNR and a small latency / PSNR plot.

The page opens at once and shows progress while the checkpoints load (in a worker thread); a bad
checkpoint or a scene mismatch shows its one-line message in the page and in the log.
Frames are rendered one at a time: camera moves that arrive during a render are merged into the next.
"""
from __future__ import annotations

import asyncio
import math
import sys
from typing import Any, Callable

from imls_lightning.base.errors import InputError

from .session import METHODS, STAGES, Frame, ViewerSession, png_data_url

IMAGE_PX = 384          # displayed size of each panel (CSS pixels)
DRAG_DEGREES_PER_PIXEL = 0.4
PLOT_W, PLOT_H = 260, 150


def log(msg: str) -> None:
    print(f"[web] {msg}", file=sys.stderr, flush=True)


def latency_psnr_svg(history, current: tuple[float, float] | None) -> str:
    """A small SVG scatter of (latency ms, PSNR dB) points, the current frame in red.

    Example:
        >>> latency_psnr_svg([("imls", 10.0, 30.0), ("recnn", 20.0, 35.0)], (10.0, 30.0)).startswith("<svg")
        True
    """
    pts = [(t, p) for _, t, p in history if math.isfinite(t) and math.isfinite(p)]
    pad = 28
    svg = [f'<svg xmlns="http://www.w3.org/2000/svg" width="{PLOT_W}" height="{PLOT_H}" data-points="{len(pts)}">',
           f'<rect x="0" y="0" width="{PLOT_W}" height="{PLOT_H}" fill="white" stroke="#ccc"/>']
    if pts:
        ts, ps = [t for t, _ in pts], [min(p, 60.0) for _, p in pts]
        t0, t1 = 0.0, max(ts) * 1.1 or 1.0
        p0, p1 = min(ps) - 1.0, max(ps) + 1.0

        def xy(t: float, p: float) -> tuple[float, float]:
            return (pad + (t - t0) / (t1 - t0) * (PLOT_W - pad - 8), PLOT_H - pad - (min(p, 60.0) - p0) / (p1 - p0) * (PLOT_H - pad - 8))

        for t, p in pts:
            x, y = xy(t, p)
            svg.append(f'<circle cx="{x:.1f}" cy="{y:.1f}" r="2.5" fill="#1f77b4" fill-opacity="0.5"/>')
        if current is not None and all(math.isfinite(v) for v in current):
            x, y = xy(*current)
            svg.append(f'<circle cx="{x:.1f}" cy="{y:.1f}" r="5" fill="#d62728"/>')
        svg.append(f'<text x="{pad}" y="{PLOT_H - 8}" font-size="10">0</text>'
                   f'<text x="{PLOT_W - 60}" y="{PLOT_H - 8}" font-size="10">{t1:.0f} ms</text>'
                   f'<text x="2" y="12" font-size="10">{p1:.1f} dB</text>'
                   f'<text x="2" y="{PLOT_H - pad}" font-size="10">{p0:.1f}</text>')
    svg.append("</svg>")
    return "".join(svg)


def stats_text(frame: Frame) -> str:
    lines = [f"{s:<17s}{frame.stages_ms[s]:8.1f} ms" for s in STAGES if s in frame.stages_ms]
    lines += [f"{'pixels ray-cast':<17s}{100 * frame.ipr:8.1f} %",
              f"{'PSNR':<17s}{frame.psnr:8.2f} dB" + ("  (exact)" if frame.psnr >= 99.9 else "")]
    if frame.method in ("imls", "adaptive"):
        lines.append(f"{'share of C':<17s}{frame.share:8.3f}" + ("  (this view's)" if frame.view_share else ""))
    return "\n".join(lines)


class WebViewer:
    """The page of one server, bound to a :class:`ViewerSession` made by ``load`` once the page is up.

    Args:
        server: a trame server (``trame.app.get_server``).
        load: builds the session (loads the checkpoints; may raise :class:`InputError`).
        title: the page's title.
    """

    def __init__(self, server, load: Callable[[], ViewerSession], title: str = "IML/S viewer"):
        self.server, self.load, self.title = server, load, title
        self.session: ViewerSession | None = None
        self._busy = False
        self._dirty = False
        self.frames = 0
        s = server.state
        s.update({"status": "Loading the checkpoints ...", "error": "", "ready": False, "method": "imls",
                  "methods": [], "share": 0.2, "share_enabled": False, "image_url": "", "mask_url": "", "error_url": "",
                  "stats_text": "", "plot_svg": "", "frames": 0, "scene": ""})
        s.change("method")(self._on_method)
        s.change("share")(self._on_share)
        server.controller.on_server_ready.add(self._start_loading)
        self._layout()

    # -- loading -------------------------------------------------------------------------------------
    def _start_loading(self, **_: Any) -> None:
        asyncio.get_event_loop().create_task(self._load())

    async def _load(self) -> None:
        state = self.server.state
        try:
            session = await asyncio.get_event_loop().run_in_executor(None, self.load)
        except InputError as err:
            log(f"error: {err}")
            with state:
                state.error, state.status = str(err), "Could not load the checkpoints."
            return
        except Exception as err:  # noqa: BLE001 (shown in the page; the server keeps running)
            log(f"error: {type(err).__name__}: {err}")
            with state:
                state.error, state.status = f"{type(err).__name__}: {err}", "Could not load the checkpoints."
            return
        self.session = session
        log(f"loaded: scene {session.scene_name}, {session.pattern.fr_size}^2, trained share {session.trained_mean:g}, "
            f"opens at share {session.share:.3f}" + (" (the evaluation's operating point)" if session.operating_point else "")
            + (", by camera distance" if session.by_distance is not None else ""))
        with state:
            state.methods = [{"title": v, "value": k} for k, v in session.methods.items()]
            state.method, state.share, state.share_enabled = session.method, session.share, session.rescalable
            state.scene, state.status, state.ready = session.scene_name, "Rendering the first frame ...", True
        self.request()

    # -- events --------------------------------------------------------------------------------------
    def on_drag(self, buttons: int, dx: float, dy: float) -> None:
        if self.session is None or not buttons:
            return
        self.session.orbit(-DRAG_DEGREES_PER_PIXEL * float(dx), DRAG_DEGREES_PER_PIXEL * float(dy))
        self.request()

    def on_wheel(self, delta_y: float) -> None:
        if self.session is None:
            return
        self.session.zoom(-1.0 if float(delta_y) > 0 else 1.0)
        self.request()

    def on_reset(self) -> None:
        if self.session is not None:
            self.session.reset()
            self.request()

    def _on_method(self, method: str, **_: Any) -> None:
        if self.session is not None and method != self.session.method:
            self._apply(lambda: self.session.set_method(method))

    def _on_share(self, share: float, **_: Any) -> None:
        if self.session is not None and share is not None and abs(float(share) - self.session.share) > 1e-9:
            self._apply(lambda: self.session.set_share(float(share)))

    def _apply(self, change: Callable[[], None]) -> None:
        try:
            change()
            self.server.state.error = ""
        except InputError as err:
            self.server.state.error = str(err)
            return
        self.request()

    # -- rendering -----------------------------------------------------------------------------------
    def request(self) -> None:
        """Render the current camera soon; moves during a render are merged into one next frame."""
        self._dirty = True
        if not self._busy:
            self._busy = True
            asyncio.get_event_loop().create_task(self._render_loop())

    async def _render_loop(self) -> None:
        try:
            while self._dirty:
                self._dirty = False
                await asyncio.sleep(0)  # let queued events update the camera first
                self.render_now()
        except Exception as err:  # noqa: BLE001 (shown in the page and the log; the server keeps running)
            msg = str(err) if isinstance(err, InputError) else f"{type(err).__name__}: {err}"
            log(f"error: {msg}")
            with self.server.state as state:
                state.error = msg
        finally:
            self._busy = False

    def render_now(self) -> Frame:
        frame = self.session.frame()
        self.frames += 1
        state = self.server.state
        with state:
            state.image_url = png_data_url(frame.image)
            state.mask_url = png_data_url(frame.mask)
            state.error_url = png_data_url(frame.error)
            state.stats_text = stats_text(frame)
            state.plot_svg = latency_psnr_svg(self.session.history, (frame.stages_ms.get("total", math.nan), frame.psnr))
            state.frames = self.frames
            state.status = f"{self.session.scene_name}: {METHODS[frame.method]}"
        return frame

    # -- page ----------------------------------------------------------------------------------------
    def _layout(self) -> None:
        from trame.ui.vuetify3 import SinglePageLayout
        from trame.widgets import html
        from trame.widgets import vuetify3 as v3

        panel = f"width:{IMAGE_PX}px;height:{IMAGE_PX}px;image-rendering:pixelated;background:#111;user-select:none"
        with SinglePageLayout(self.server) as layout:
            layout.title.set_text(self.title)
            with layout.toolbar:
                v3.VSpacer()
                v3.VSelect(v_model=("method",), items=("methods",), item_title="title", item_value="value",
                           label="method", density="compact", hide_details=True, style="max-width:300px",
                           disabled=("!ready",), id="method-select")
                v3.VSlider(v_model=("share",), min=0.01, max=1.0, step=0.01, label="share of C", thumb_label=True,
                           density="compact", hide_details=True, style="max-width:300px;margin-left:16px",
                           disabled=("!ready || !share_enabled",), id="share-slider")
                v3.VBtn("reset camera", click=self.on_reset, variant="text", disabled=("!ready",))
            with layout.content:
                with v3.VContainer(fluid=True):
                    html.Div("{{ status }}", id="status", style="margin-bottom:8px")
                    html.Div("{{ error }}", id="error", v_show="error",
                             style="color:#b00020;font-weight:bold;margin-bottom:8px")
                    with html.Div(style="display:flex;gap:12px;flex-wrap:wrap"):
                        with html.Div():
                            html.Div("image (drag: orbit, wheel: zoom)")
                            html.Img(src=("image_url",), id="frame", draggable="false", style=panel + ";cursor:grab",
                                     mousemove=(self.on_drag, "[$event.buttons, $event.movementX, $event.movementY]"),
                                     wheel=(self.on_wheel, "[$event.deltaY]"))
                        with html.Div():
                            html.Div("pixels ray-cast")
                            html.Img(src=("mask_url",), id="mask", draggable="false", style=panel)
                        with html.Div():
                            html.Div("error against the ground truth (x4)")
                            html.Img(src=("error_url",), id="error-map", draggable="false", style=panel)
                    with html.Div(style="display:flex;gap:24px;margin-top:12px"):
                        html.Pre(v_text=("stats_text",), id="stats", style="font-size:13px")
                        with html.Div():
                            html.Div("latency (ms) / PSNR (dB), this session")
                            html.Div(v_html=("plot_svg",), id="plot")
                    html.Div("{{ frames }}", id="frames", style="display:none")
