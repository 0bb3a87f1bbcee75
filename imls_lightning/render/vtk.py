"""Offscreen VTK ray casting of a :class:`~imls_lightning.render.scene.Scene` (the renderer of record).

The pipeline (image data, transfer functions, mapper, render window) is built once per scene and
reused for every view: only the camera changes between renders.

Details that make the pixels a function of the scene and the view alone (all found by reading
VTK's fixed-point mapper and comparing with our own caster, :mod:`imls_lightning.render.numba`):

* the light is an explicit headlight whose *ambient* colour is white. VTK's automatic light has a
  black ambient colour, so the fixed-point mapper silently dropped ``scene.shading.ambient``;
* the per-voxel normals are computed single-threaded (first render). VTK computes them in one z
  slab per thread with one-sided differences at every slab boundary, so the picture depended on
  the number of threads (61 dB between 1 and 2 threads, 46 dB for 3 on ct_head);
* the sample distance is the scene's resolved one (:func:`imls_lightning.render.scene.resolve_sample_distance`;
  ``auto`` is half the smallest voxel spacing, after VTK's ``LockSampleDistanceToInputSpacing``), set
  explicitly with VTK's own locking and automatic adjustment off, so both renderers step alike; the opacity is
  corrected for it through ``ScalarOpacityUnitDistance`` (``scene.opacity_unit_distance``);
* the clipping range is set from the volume's bounds alone (VTK starts its rays at the near plane
  and spaces the samples from there), so extra geometry never moves the samples;
* with the fixed-point mapper the image is read from the mapper's own ray-cast image (15-bit
  premultiplied RGBA, one ray per pixel centre) and composited over the background here. VTK
  shows that image as a texture whose texel centres are stretched over one pixel less than the
  image (``vtkOpenGLRayCastImageDisplayHelper``: texture coordinates run from the first to the last
  texel *centre*), i.e. a view-dependent bilinear resampling that blurs and shifts the picture by up
  to half a pixel. A one-pixel frame is rendered around the image and cut off, because the mapper
  drops its last row/column when the volume is cut by the viewport; and a frame in which the mapper
  did not run (volume culled) gives the background, not the mapper's previous image.

``render_pixels`` ray-casts a pixel subset: every other pixel whose ray would reach the volume is
covered by opaque geometry just behind the near plane (one quad per horizontal run of such pixels),
and the mapper's intersecting-geometry mixing ends those rays before their first sample (see
:meth:`VTKRenderer.render_pixels`).
"""
from __future__ import annotations

import ctypes
import math
import os
import re
import time

import numpy as np

from imls_lightning.base.errors import InputError

from .camera import camera_basis, render_request
from .scene import Scene

# Prefer a headless EGL window; VTK otherwise tries X first and warns when there is no display.
os.environ.setdefault("VTK_DEFAULT_OPENGL_WINDOW", "vtkEGLRenderWindow")


class VTKRenderer:
    """Ray-cast full frames (and pixel subsets) with VTK.

    Args:
        scene: what to render.
        mapper: ``"fixed_point"`` (CPU, default) or ``"gpu"`` (``vtkGPUVolumeRayCastMapper``).
        threads: CPU threads for the fixed-point mapper (``0``: VTK's default).
        exact_pixels: fixed-point mapper only: read the mapper's ray-cast image (one ray per pixel
            centre) instead of the displayed window, which VTK resamples (see the module notes).

    Attributes:
        last_render_seconds: wall time of VTK's last render call.
        last_blocked_pixels: points drawn by the last ``render_pixels`` call.

    Example:
        >>> r = VTKRenderer(scene)                                  # doctest: +SKIP
        >>> img = r.render([0, 0, 3, 0, 0, 0, 0, 1, 0], 128)        # (128, 128, 3) uint8
        >>> r.render_pixels([0, 0, 3, 0, 0, 0, 0, 1, 0], 128, np.array([8256]))   # (1, 3) uint8
    """

    name = "vtk"

    def __init__(self, scene: Scene, mapper: str = "fixed_point", threads: int = 0, exact_pixels: bool = True):
        import vtk  # heavy import kept local: importing the ray casters must stay cheap
        from vtk.util import numpy_support as ns

        self.scene = scene
        self._vtk = vtk
        self._ns = ns
        vol = scene.volume
        img = vtk.vtkImageData()
        x, y, z = vol.dims
        img.SetDimensions(x, y, z)
        img.SetSpacing(*[float(s) for s in vol.normalized_spacing])
        img.SetOrigin(*[float(o) for o in vol.origin])
        flat = vol.data.reshape(-1)  # a view for C-contiguous (memory-mapped) data: no copy
        if not flat.flags.c_contiguous:
            flat = np.ascontiguousarray(flat)
        self._scalars_ref = flat  # VTK does not own the buffer; keep it alive
        arr = ns.numpy_to_vtk(flat, deep=False)
        arr.SetName("scalars")
        img.GetPointData().SetScalars(arr)
        self._image = img

        tf = scene.transfer_function
        ctf = vtk.vtkColorTransferFunction()
        for xs, r, g, b in tf.color:
            ctf.AddRGBPoint(float(vol.to_raw(xs)), float(r), float(g), float(b))
        otf = vtk.vtkPiecewiseFunction()
        for xs, a in tf.opacity:
            otf.AddPoint(float(vol.to_raw(xs)), float(a))
        prop = vtk.vtkVolumeProperty()
        prop.SetColor(ctf)
        prop.SetScalarOpacity(otf)
        prop.SetScalarOpacityUnitDistance(float(scene.opacity_unit_distance))
        prop.SetInterpolationTypeToLinear()
        sh = scene.shading
        if sh.enabled:
            prop.ShadeOn()
            prop.SetAmbient(float(sh.ambient))
            prop.SetDiffuse(float(sh.diffuse))
            prop.SetSpecular(float(sh.specular))
            prop.SetSpecularPower(float(sh.specular_power))
        else:
            prop.ShadeOff()

        if mapper == "fixed_point":
            m = vtk.vtkFixedPointVolumeRayCastMapper()
            m.SetImageSampleDistance(1.0)
            m.SetMinimumImageSampleDistance(1.0)
            m.SetMaximumImageSampleDistance(1.0)
            m.SetInteractiveSampleDistance(float(scene.sample_distance))
            m.LockSampleDistanceToInputSpacingOff()
            m.IntermixIntersectingGeometryOn()  # render_pixels ends rays at its blocking points
            # VTK computes the per-voxel normals once, in z slabs, one per thread, and takes
            # one-sided differences at every slab boundary: the picture would depend on the
            # thread count. One thread computes them (first render, below); then all cast rays.
            m.SetNumberOfThreads(1)
        elif mapper == "gpu":
            m = vtk.vtkGPUVolumeRayCastMapper()
            m.LockSampleDistanceToInputSpacingOff()
        else:
            raise InputError(f"renderer.mapper={mapper!r}: expected 'fixed_point' or 'gpu'")
        m.AutoAdjustSampleDistancesOff()
        m.SetSampleDistance(float(scene.sample_distance))
        m.SetInputData(img)
        actor = vtk.vtkVolume()
        actor.SetMapper(m)
        actor.SetProperty(prop)

        ren = vtk.vtkRenderer()
        ren.AddVolume(actor)
        ren.SetBackground(*scene.background)
        # A headlight (at the camera, along the view direction) with a white ambient colour: the
        # shading tables of the fixed-point mapper multiply the ambient coefficient by it, and
        # VTK's automatic light is black there, which would drop scene.shading.ambient.
        light = vtk.vtkLight()
        light.SetLightTypeToHeadlight()
        light.SetAmbientColor(1.0, 1.0, 1.0)
        light.SetDiffuseColor(1.0, 1.0, 1.0)
        light.SetSpecularColor(1.0, 1.0, 1.0)
        light.SetIntensity(1.0)
        ren.AutomaticLightCreationOff()
        ren.AddLight(light)
        ren.TwoSidedLightingOn()  # VTK's default, stated: the shading uses |n . v|
        win = vtk.vtkRenderWindow()
        win.SetOffScreenRendering(1)
        win.SetMultiSamples(0)
        win.AddRenderer(ren)
        self._mapper, self._renderer, self._window, self._actor = m, ren, win, actor
        self._mapper_kind = mapper
        self._exact = bool(exact_pixels) and mapper == "fixed_point"
        # The fixed-point mapper drops the last row/column of its image when the volume's
        # projection is cut by the viewport (its in-use image size is rounded down); a one-pixel
        # frame around the image, rendered with a matching wider view angle and cut off, keeps
        # every pixel of the requested image a ray through its centre.
        self._margin = 1 if self._exact else 0
        self._bounds = [float(b) for b in np.asarray(vol.bounds).reshape(-1)]  # xmin, xmax, ymin, ...
        self._bg = np.asarray(scene.background, np.float64)
        self._blockers = None  # the points actor of render_pixels, built on first use
        # Did the mapper cast rays in the last frame? Not when VTK's culler dropped the volume
        # (outside the frustum): its ray-cast image then still holds the previous frame.
        self._cast_flag = [False]
        if mapper == "fixed_point":
            flag = self._cast_flag
            m.AddObserver(vtk.vtkCommand.VolumeMapperRenderStartEvent, lambda *_: flag.__setitem__(0, True))
        self._size = None  # image side m; the window is m + 2 * margin
        self.last_render_seconds = 0.0
        self.last_blocked_pixels = 0
        if mapper == "fixed_point":
            if sh.enabled:  # the normals are computed now, single-threaded (see above)
                self._set_camera([0.0, 0.0, 4.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0], 8)
                self._window.Render()
            m.SetNumberOfThreads(int(threads) if threads else vtk.vtkMultiThreader.GetGlobalDefaultNumberOfThreads())

    def _set_camera(self, view, resolution) -> np.ndarray:
        v, m, _ = render_request(view, resolution)
        from .numba import clipping_range

        w = m + 2 * self._margin
        if self._size != m:
            self._window.SetSize(w, w)
            self._size = m
        angle = float(self.scene.view_angle)
        cam = self._renderer.GetActiveCamera()
        cam.SetPosition(*v[0:3])
        cam.SetFocalPoint(*v[3:6])
        cam.SetViewUp(*v[6:9])
        cam.OrthogonalizeViewUp()
        cam.SetViewAngle(math.degrees(2.0 * math.atan(math.tan(math.radians(angle) / 2.0) * w / m)))
        # VTK's ResetCameraClippingRange(volume bounds) for the requested camera, computed by the
        # one shared function: the samples are spaced from the near plane, so the numba caster
        # and render_pixels' extra geometry must see exactly this near plane
        cam.SetClippingRange(*clipping_range(v, np.asarray(self._bounds).reshape(3, 2), angle))
        return v

    def _render_window(self) -> None:
        self._cast_flag[0] = False
        t0 = time.perf_counter()
        self._window.Render()
        self.last_render_seconds = time.perf_counter() - t0

    def render(self, view, resolution: int) -> np.ndarray:
        """Render a full frame: ``(m, m, 3)`` uint8, row 0 at the top.

        The wall time of VTK's render call alone is left in ``last_render_seconds``.
        """
        self._set_camera(view, resolution)
        self._render_window()
        return self._read_image()

    # ---- reading the image ------------------------------------------------------------------
    def _read_image(self) -> np.ndarray:
        return self._read_raycast_image() if self._exact else self._read_window()

    def _read_window(self) -> np.ndarray:
        m, k = self._size, self._margin
        w = m + 2 * k
        buf = self._vtk.vtkUnsignedCharArray()
        # front=0: the back buffer just rendered; RGB of the whole window, bottom row first
        self._window.GetPixelData(0, 0, w - 1, w - 1, 0, buf, 0)
        a = self._ns.vtk_to_numpy(buf).reshape(w, w, 3)
        return np.ascontiguousarray(a[::-1][k : k + m, k : k + m])

    def _volume_in_view(self) -> bool:
        """VTK's own test (``ComputeRowBounds``): does the box project into the viewport at all?

        When it does not, the mapper gives up on the frame but still shows its previous image.
        """
        ren = self._renderer
        b = np.asarray(self._bounds).reshape(3, 2)
        cam = ren.GetActiveCamera()
        mat = cam.GetCompositeProjectionTransformMatrix(1.0, 0.0, 1.0)
        mm = np.array([[mat.GetElement(i, j) for j in range(4)] for i in range(4)])
        corners = np.array([[b[0, i], b[1, j], b[2, k], 1.0] for k in (0, 1) for j in (0, 1) for i in (0, 1)])
        p = corners @ mm.T
        behind = p[:, 3] <= 0
        if behind.any():  # a corner behind the camera: VTK casts the whole viewport
            return True
        ndc = p[:, :3] / p[:, 3:4]
        z = ndc[:, 2] * 0.5 + 0.5
        if z.min() < 0.001 or z.max() > 0.9999:
            return True
        w = self._size + 2 * self._margin
        lo = (ndc[:, :2].min(axis=0) + 1.0) * 0.5 * w - 2
        hi = (ndc[:, :2].max(axis=0) + 1.0) * 0.5 * w + 2
        return not bool(np.any((hi < 0) | (lo > w - 1)))

    def _raycast_tile(self):
        """``(rgba, origin)``: the mapper's ray-cast image in use (15-bit premultiplied RGBA, rows
        bottom-up, a view of VTK's buffer) and its origin in the window; ``None`` if the mapper
        cast nothing this frame (then every pixel is background)."""
        if not (self._cast_flag[0] and self._volume_in_view()):
            return None
        rci = self._mapper.GetRayCastImage()
        mem = rci.GetImageMemorySize()
        use = rci.GetImageInUseSize()
        org = rci.GetImageOrigin()
        match = re.fullmatch(r"_([0-9a-fA-F]+)_p_void", str(rci.GetImage()))
        if match is None or int(match.group(1), 16) == 0:
            raise RuntimeError("VTK's ray-cast image pointer is not readable; use exact_pixels=False")
        n = int(mem[0]) * int(mem[1]) * 4
        raw = np.ctypeslib.as_array((ctypes.c_uint16 * n).from_address(int(match.group(1), 16)))
        return raw.reshape(mem[1], mem[0], 4)[: use[1], : use[0]], (int(org[0]), int(org[1]))

    def _composite(self, rgba: np.ndarray) -> np.ndarray:
        """15-bit premultiplied RGBA ``(..., 4)`` over the background -> uint8 RGB (as the display's
        GL_ONE, GL_ONE_MINUS_SRC_ALPHA blend, rounded to nearest)."""
        # float32 is exact enough for 15-bit inputs and halves the cost of this per-frame step
        f = rgba.astype(np.float32) * np.float32(1.0 / 32767.0)
        rgb = np.minimum(f[..., :3] + (np.float32(1.0) - f[..., 3:4]) * self._bg.astype(np.float32), np.float32(1.0))
        return np.floor(rgb * np.float32(255.0) + np.float32(0.5)).astype(np.uint8)

    def _read_raycast_image(self, pixels: np.ndarray | None = None) -> np.ndarray:
        """The ray-cast image over the background: ``(m, m, 3)``, row 0 on top, or the ``(K, 3)``
        colours of flat pixel indices ``pixels`` (only those are converted)."""
        m, k = self._size, self._margin
        w = m + 2 * k
        bg = np.floor(self._bg * 255.0 + 0.5).astype(np.uint8)
        tile = self._raycast_tile()
        if pixels is not None:
            out = np.empty((pixels.shape[0], 3), np.uint8)
            out[:] = bg
            if tile is None:
                return out
            rgba, (ox, oy) = tile
            row, col = np.divmod(pixels, m)
            ty = (w - 1 - (row + k)) - oy  # window rows run bottom-up from the image origin
            tx = col + k - ox
            inside = (ty >= 0) & (ty < rgba.shape[0]) & (tx >= 0) & (tx < rgba.shape[1])
            out[inside] = self._composite(rgba[ty[inside], tx[inside]])
            return out
        out = np.empty((w, w, 3), np.uint8)
        out[:] = bg
        if tile is not None:
            rgba, (ox, oy) = tile
            r0 = w - (oy + rgba.shape[0])
            out[r0 : r0 + rgba.shape[0], ox : ox + rgba.shape[1]] = self._composite(rgba)[::-1]
        return out[k : k + m, k : k + m]

    # ---- selective rendering --------------------------------------------------------------
    def _blocker_actor(self):
        if self._blockers is None:
            vtk = self._vtk
            poly = vtk.vtkPolyData()
            mapper = vtk.vtkPolyDataMapper()
            mapper.SetInputData(poly)
            mapper.ScalarVisibilityOff()
            actor = vtk.vtkActor()
            actor.SetMapper(mapper)
            p = actor.GetProperty()
            p.LightingOff()
            p.SetColor(0.0, 0.0, 0.0)
            actor.PickableOff()
            actor.VisibilityOff()
            self._renderer.AddActor(actor)
            self._blockers = (poly, actor)
        return self._blockers

    def _blocker_quads(self, view: np.ndarray, block: np.ndarray, depth: float) -> np.ndarray:
        """Corners ``(R, 4, 3)`` of one quad per horizontal run of blocked pixels.

        A quad spans the pixel *edges* of its run, on the plane at view depth ``depth``, so it covers
        exactly the centres of the run's pixels (0.5 pixel from every edge: no rasterization ties).
        """
        m = self._size
        pad = np.zeros((m, m + 2), np.int8)
        pad[:, 1:-1] = block.reshape(m, m)
        d = np.diff(pad, axis=1)
        rows, x0 = np.nonzero(d == 1)  # run starts (pixel columns)
        _, x1 = np.nonzero(d == -1)  # one past the run ends
        eye, f, r, u = camera_basis(view)
        t = math.tan(math.radians(float(self.scene.view_angle)) / 2.0)
        xs0 = (2.0 * x0 / m - 1.0) * t
        xs1 = (2.0 * x1 / m - 1.0) * t
        ys0 = (1.0 - 2.0 * rows / m) * t  # top edge of the row
        ys1 = (1.0 - 2.0 * (rows + 1) / m) * t
        # a point of the plane at depth z on the ray f + xs r + ys u is eye + z (f + xs r + ys u)
        corners = np.stack([np.stack([xs0, ys0], 1), np.stack([xs1, ys0], 1),
                            np.stack([xs1, ys1], 1), np.stack([xs0, ys1], 1)], axis=1)
        return eye + depth * (f + corners[..., :1] * r + corners[..., 1:] * u)

    def render_pixels(self, view, resolution: int, pixels) -> np.ndarray:
        """Ray-cast only ``pixels`` (flat raster indices ``(K,)``) and return their ``(K, 3)`` colours.

        Every pixel not asked for whose ray would reach the volume is covered by opaque geometry
        just behind the near clipping plane (so in front of the volume): one quad per horizontal
        run of such pixels, covering exactly their centres. The fixed-point mapper reads the depth
        buffer (``IntermixIntersectingGeometry``) and ends those rays before their first sample;
        the requested pixels see a cleared depth buffer and are cast exactly as in :meth:`render`.
        ``last_render_seconds`` is the time of VTK's render call; ``last_blocked_pixels`` the number
        of pixels covered. An empty ``pixels`` costs nothing.
        """
        from .numba import ray_hit_mask

        if self._mapper_kind != "fixed_point":
            raise InputError("renderer.mapper=gpu: render_pixels needs the fixed_point mapper (or renderer=numba)")
        v, m, pix = render_request(view, resolution, pixels)
        if pix.shape[0] == 0:
            self.last_render_seconds = 0.0
            self.last_blocked_pixels = 0
            return np.zeros((0, 3), np.uint8)
        self._set_camera(v, m)
        near, far = self._renderer.GetActiveCamera().GetClippingRange()
        block = ray_hit_mask(v, m, float(self.scene.view_angle), np.asarray(self._bounds).reshape(3, 2), (near, far))
        block[pix] = False
        n_blocked = int(np.count_nonzero(block))
        poly, actor = self._blocker_actor()
        if n_blocked:
            quads = self._blocker_quads(v, block, near * (1.0 + 1e-3)).reshape(-1, 3)
            vtk, ns = self._vtk, self._ns
            points = vtk.vtkPoints()
            points.SetData(ns.numpy_to_vtk(quads, deep=True))
            cells = vtk.vtkCellArray()
            nq = quads.shape[0] // 4
            cells.SetData(ns.numpy_to_vtkIdTypeArray(np.arange(0, 4 * nq + 1, 4, dtype=np.int64), deep=True),
                          ns.numpy_to_vtkIdTypeArray(np.arange(4 * nq, dtype=np.int64), deep=True))
            poly.SetPoints(points)
            poly.SetPolys(cells)
            poly.Modified()
            actor.VisibilityOn()
        try:
            self._render_window()
        finally:
            actor.VisibilityOff()
        self.last_blocked_pixels = n_blocked
        if self._exact:
            return self._read_raycast_image(pix)
        return self._read_window().reshape(-1, 3)[pix]

    def close(self) -> None:
        self._window.Finalize()
