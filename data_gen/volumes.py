"""Volume readers and :func:`load_volume`, the one entry point from a ``scene.volume`` config node.

Formats (by extension):

=================  ==========================================================================
``.raw``           headerless, little-endian, x fastest; named ``name_XxYxZ_dtype.raw`` (Open
                   SciVis convention) or given ``dims``/``dtype``; always memory-mapped read-only
``.vti``           VTK XML image data (``vtkXMLImageDataReader``); point scalars, spacing
``.nrrd``/``.nhdr`` NRRD via pynrrd; spacing from ``spacings`` or ``space directions``; raw encoded
                   data (attached or detached) is memory-mapped, compressed data is read by pynrrd
``.mha``/``.mhd``  MetaImage via a small header parser: uncompressed data (``LOCAL`` or one
                   detached file) is memory-mapped, zlib-compressed data is inflated; multi-file
                   (``LIST``/pattern) data falls back to VTK's ``vtkMetaImageReader``
``.nii``/``.nii.gz`` NIfTI-1/2 via nibabel; spacing from the header zooms; the on-disk (X, Y, Z)
                   Fortran array *is* a C-order (Z, Y, X) array, so the transpose is free
=================  ==========================================================================

Why our own MetaImage parser: the header is a dozen ``key = value`` lines, and parsing it lets a
multi-GB ``.mhd``/``.raw`` pair be memory-mapped like a ``.raw`` file; ``vtkMetaImageReader`` always
reads the whole file into VTK memory. VTK stays as the fallback for the rare multi-file layouts.

Every reader returns ``(data, spacing, info)``: ``data`` is ``(Z, Y, X)`` C-contiguous in the file's
dtype (native byte order), ``spacing`` is ``(sx, sy, sz)``. :func:`load_volume` then scans the
values in chunks (finite min/max, NaN/Inf count) without making a float copy, optionally clips the
value range to percentiles, and builds the :class:`~imls_lightning.render.volume.Volume`.

Example:
    >>> vol = load_volume({"kind": "file", "path": "ct_head_256x256x108_int16.raw",
    ...                    "spacing": [0.957, 0.957, 1.5]})                    # doctest: +SKIP
    >>> vol.dims, vol.data.dtype, vol.value_range                               # doctest: +SKIP
    ((256, 256, 108), dtype('int16'), (-1024.0, 2986.0))
"""
from __future__ import annotations

import os
import re
import zlib
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from imls_lightning.base.errors import InputError
from imls_lightning.base.validate import check_numbers
from imls_lightning.render.volume import Volume

#: dtype names of the Open SciVis ``.raw`` convention -> little-endian numpy dtypes
RAW_DTYPES: dict[str, np.dtype] = {
    name: np.dtype(code)
    for name, code in [
        ("uint8", "u1"), ("int8", "i1"), ("uint16", "<u2"), ("int16", "<i2"),
        ("uint32", "<u4"), ("int32", "<i4"), ("float32", "<f4"), ("float64", "<f8"),
    ]
}

#: file extensions :func:`read_volume` understands (longest match wins: ``.nii.gz`` before ``.gz``)
SUPPORTED_EXTENSIONS = (".raw", ".vti", ".nrrd", ".nhdr", ".mha", ".mhd", ".nii", ".nii.gz")

#: keys of the ``scene.volume`` config node (keys starting with ``_`` are ignored)
VOLUME_CONFIG_KEYS = (
    "kind", "path", "dims", "dtype", "spacing", "clip_percentiles", "nan_to", "name",
    "generator", "size", "seed", "stream_to",
)

# ``name_XxYxZ_dtype.raw``; the name itself may contain underscores (``ct_head_256x256x108_int16``)
_RAW_NAME = re.compile(r"^(?P<name>.+)_(?P<x>\d+)x(?P<y>\d+)x(?P<z>\d+)_(?P<dtype>[A-Za-z0-9]+)\.raw$", re.IGNORECASE)

# voxels per chunk when scanning values (16 MiB of float32): bounded memory for any file size
_CHUNK_VOXELS = 1 << 22
# at most this many voxels feed the percentile estimate (strided subsample beyond)
_PERCENTILE_SAMPLES = 1 << 23


# ---------------------------------------------------------------------------------------------
# small validators shared by the readers and load_volume
# ---------------------------------------------------------------------------------------------
def _extension(path: Path) -> str:
    name = path.name.lower()
    for ext in sorted(SUPPORTED_EXTENSIONS, key=len, reverse=True):
        if name.endswith(ext):
            return ext
    return "".join(path.suffixes[-2:]).lower() or "(none)"


def _check_spacing(spacing: Any, key: str) -> tuple[float, float, float]:
    """Three positive finite numbers (a single number means isotropic)."""
    return check_numbers(spacing, key, 3, lo=0, lo_open=True, broadcast=True,
                         what="three positive numbers (sx, sy, sz)")


def _check_dims(dims: Any, key: str) -> tuple[int, int, int]:
    return check_numbers(dims, key, 3, lo=2, integer=True, what="three integers (x, y, z), each >= 2")


def _check_dtype(dtype: Any, what: str) -> np.dtype:
    key = str(dtype).lower()
    if key not in RAW_DTYPES:
        raise InputError(f"{what}={dtype!r}: unknown dtype, expected one of {', '.join(RAW_DTYPES)}")
    return RAW_DTYPES[key]


def _native(data: np.ndarray) -> np.ndarray:
    """Native byte order (VTK and numba read the buffer as is). Copies big-endian data only."""
    return data if data.dtype.isnative else data.astype(data.dtype.newbyteorder("="))


def _as_zyx(data: np.ndarray, what: str) -> np.ndarray:
    """Drop trailing singleton axes (e.g. NIfTI's t=1) and require a 3D array."""
    while data.ndim > 3 and data.shape[-1] == 1:
        data = data[..., 0]
    if data.ndim != 3:
        raise InputError(f"{what}: expected a 3D scalar volume, got an array of shape {data.shape}")
    return data


def _memmap(path: Path, dtype: np.dtype, shape_zyx: tuple[int, int, int], offset: int, what: str) -> np.memmap:
    """Read-only memory map of a (Z, Y, X) block; checks the file is large enough first."""
    need = int(np.prod(shape_zyx, dtype=np.int64)) * dtype.itemsize
    size = path.stat().st_size
    if size - offset < need:
        raise InputError(
            f"{what}: data file {path} has {size - offset} bytes of data but dims "
            f"{shape_zyx[2]}x{shape_zyx[1]}x{shape_zyx[0]} x {dtype.name} ({dtype.itemsize} bytes) need {need} bytes"
        )
    return np.memmap(path, dtype=dtype, mode="r", offset=offset, shape=shape_zyx, order="C")


# ---------------------------------------------------------------------------------------------
# readers: each returns (data (Z, Y, X), spacing (sx, sy, sz) or None if the file has none, info)
# ---------------------------------------------------------------------------------------------
def parse_raw_name(path: str | os.PathLike) -> dict[str, Any] | None:
    """Parse an Open SciVis file name ``name_XxYxZ_dtype.raw``.

    Returns ``{"name", "dims" (x, y, z), "dtype" (str)}`` or ``None`` if the name does not follow
    the convention.

    Example:
        >>> parse_raw_name("ct_head_256x256x108_int16.raw")
        {'name': 'ct_head', 'dims': (256, 256, 108), 'dtype': 'int16'}
    """
    m = _RAW_NAME.match(Path(path).name)
    if m is None:
        return None
    return {"name": m["name"], "dims": (int(m["x"]), int(m["y"]), int(m["z"])), "dtype": m["dtype"].lower()}


def read_raw(path: Path, dims=None, dtype=None, what: str | None = None):
    """Memory-map a headerless little-endian ``.raw`` file (x fastest) as ``(Z, Y, X)``.

    ``dims`` ``(x, y, z)`` and ``dtype`` override what the file name says; the file size must be
    exactly ``x * y * z * itemsize``.
    """
    what = what or str(path)
    parsed = parse_raw_name(path)
    if dims is None and parsed is None:
        raise InputError(
            f"{what}: raw file name does not follow the convention name_XxYxZ_dtype.raw "
            f"(e.g. ct_head_256x256x108_int16.raw) and no dims were given (scene.volume.dims=[x,y,z])"
        )
    if dtype is None and parsed is None:
        raise InputError(f"{what}: raw file name does not name a dtype and none was given (scene.volume.dtype)")
    xyz = _check_dims(dims, "scene.volume.dims") if dims is not None else parsed["dims"]
    dt = _check_dtype(dtype, "scene.volume.dtype") if dtype is not None else _check_dtype(parsed["dtype"], f"{what}: dtype in file name")
    need = int(np.prod(xyz, dtype=np.int64)) * dt.itemsize
    size = path.stat().st_size
    if size != need:
        raise InputError(
            f"{what}: file has {size} bytes but dims {xyz[0]}x{xyz[1]}x{xyz[2]} x {dt.name} "
            f"({dt.itemsize} bytes) need {need} bytes"
        )
    data = np.memmap(path, dtype=dt, mode="r", shape=(xyz[2], xyz[1], xyz[0]), order="C")
    info = {
        "format": "raw",
        "dims_from": "config" if dims is not None else "file name",
        "dtype_from": "config" if dtype is not None else "file name",
    }
    return _native(data), None, info


def read_vti(path: Path, what: str | None = None):
    """VTK XML image data: the active point scalars (or the first point array), one component."""
    import vtk  # heavy import kept local
    from vtk.util import numpy_support as ns

    what = what or str(path)
    reader = vtk.vtkXMLImageDataReader()
    if not reader.CanReadFile(str(path)):
        raise InputError(f"{what}: not a readable VTK XML image data (.vti) file")
    reader.SetFileName(str(path))
    reader.Update()
    img = reader.GetOutput()
    pd = img.GetPointData()
    arr = pd.GetScalars() or (pd.GetArray(0) if pd.GetNumberOfArrays() else None)
    if arr is None:
        raise InputError(f"{what}: the .vti file has no point data array (cell data is not supported)")
    if arr.GetNumberOfComponents() != 1:
        raise InputError(f"{what}: point array '{arr.GetName()}' has {arr.GetNumberOfComponents()} components, expected 1 (scalars)")
    x, y, z = img.GetDimensions()
    # vtk_to_numpy shares VTK's buffer and keeps the vtk array alive through .base: no copy
    data = ns.vtk_to_numpy(arr).reshape(z, y, x)
    info = {"format": "vti", "array": arr.GetName() or "", "origin": [float(o) for o in img.GetOrigin()]}
    return _native(data), tuple(float(s) for s in img.GetSpacing()), info


def read_nrrd(path: Path, what: str | None = None):
    """NRRD (``.nrrd`` attached, ``.nhdr`` detached header). Raw encoding is memory-mapped."""
    import nrrd

    what = what or str(path)
    try:
        with open(path, "rb") as fh:
            header = nrrd.read_header(fh)
            header_end = fh.tell()  # attached data starts right after the blank line
        sizes = [int(s) for s in header["sizes"]]
    except (nrrd.NRRDError, KeyError, ValueError, StopIteration) as err:
        raise InputError(f"{what}: not a valid NRRD header ({err})") from None
    if len(sizes) != 3:
        raise InputError(f"{what}: expected a 3D NRRD, got dimension {len(sizes)} with sizes {sizes}")
    datafile = header.get("data file", header.get("datafile"))
    line_skip = int(header.get("line skip", header.get("lineskip", 0)))
    byte_skip = int(header.get("byte skip", header.get("byteskip", 0)))
    shape = (sizes[2], sizes[1], sizes[0])
    single_file = datafile is None or not (str(datafile).startswith("LIST") or len(str(datafile).split()) > 1)
    try:  # pynrrd's own type/endian mapping (not public API: without it, pynrrd reads the data)
        dtype = np.dtype(nrrd.reader._determine_datatype(header))
    except Exception:
        dtype = None
    if dtype is not None and header.get("encoding") == "raw" and line_skip == 0 and single_file:
        dpath = path if datafile is None else (path.parent / datafile if not os.path.isabs(datafile) else Path(datafile))
        if not dpath.is_file():
            raise InputError(f"{what}: detached data file {dpath} not found")
        offset = header_end if datafile is None else 0
        nbytes = int(np.prod(shape, dtype=np.int64)) * dtype.itemsize
        offset = dpath.stat().st_size - nbytes if byte_skip == -1 else offset + byte_skip
        data = _memmap(dpath, dtype, shape, max(offset, 0), what)
    else:
        try:
            data, header = nrrd.read(str(path), index_order="C")
        except (nrrd.NRRDError, OSError, ValueError, EOFError, zlib.error) as err:  # zlib.error: corrupt gzip data
            raise InputError(f"{what}: cannot read NRRD data ({type(err).__name__}: {err}); the file is damaged or truncated") from None
        data = np.ascontiguousarray(data)
    spacing = None
    if "spacings" in header:
        spacing = tuple(float(s) for s in header["spacings"])
    elif header.get("space directions") is not None:
        dirs = np.asarray(header["space directions"], np.float64)
        spacing = tuple(float(v) for v in np.linalg.norm(dirs, axis=1))
    info = {"format": "nrrd", "encoding": str(header.get("encoding")), "detached": datafile is not None}
    return _native(data), spacing, info


_MET_TYPES = {
    "MET_UCHAR": "u1", "MET_CHAR": "i1", "MET_USHORT": "u2", "MET_SHORT": "i2", "MET_UINT": "u4",
    "MET_INT": "i4", "MET_ULONG_LONG": "u8", "MET_LONG_LONG": "i8", "MET_FLOAT": "f4", "MET_DOUBLE": "f8",
    "MET_ULONG": "u4", "MET_LONG": "i4",  # MetaIO writes 32-bit for these
}


def _parse_metaimage_header(path: Path, what: str) -> tuple[dict[str, str], int]:
    """``key = value`` lines up to and including ``ElementDataFile``; returns (fields, header bytes)."""
    fields: dict[str, str] = {}
    pos = 0
    with open(path, "rb") as fh:
        for raw in fh:
            pos += len(raw)
            line = raw.decode("latin-1").strip()
            if not line:
                continue
            if "=" not in line:
                raise InputError(f"{what}: not a MetaImage header (line without '=': {line[:40]!r})")
            key, val = (s.strip() for s in line.split("=", 1))
            fields[key] = val
            if key == "ElementDataFile":  # always the last field; LOCAL data follows it
                break
            if pos > 1 << 16:
                raise InputError(f"{what}: MetaImage header not terminated by ElementDataFile")
    if "ElementDataFile" not in fields:
        raise InputError(f"{what}: MetaImage header has no ElementDataFile field")
    return fields, pos


def read_metaimage(path: Path, what: str | None = None):
    """MetaImage ``.mha`` / ``.mhd``: uncompressed data memory-mapped, zlib data inflated."""
    what = what or str(path)
    f, header_end = _parse_metaimage_header(path, what)
    try:
        ndims = int(f.get("NDims", "0"))
        xyz = [int(v) for v in f["DimSize"].split()]
    except (KeyError, ValueError):
        raise InputError(f"{what}: MetaImage header needs NDims and DimSize") from None
    if ndims != 3 or len(xyz) != 3:
        raise InputError(f"{what}: expected a 3D MetaImage, got NDims={ndims} DimSize={xyz}")
    if int(f.get("ElementNumberOfChannels", "1")) != 1:
        raise InputError(f"{what}: ElementNumberOfChannels={f['ElementNumberOfChannels']}, expected 1 (scalars)")
    etype = f.get("ElementType", "")
    if etype not in _MET_TYPES:
        raise InputError(f"{what}: ElementType={etype!r} unsupported, expected one of {', '.join(sorted(_MET_TYPES))}")
    msb = (f.get("BinaryDataByteOrderMSB") or f.get("ElementByteOrderMSB") or "False").lower() == "true"
    dtype = np.dtype(_MET_TYPES[etype]).newbyteorder(">" if msb else "<")
    spacing = None
    for key in ("ElementSpacing", "ElementSize"):
        if key in f:
            spacing = tuple(float(v) for v in f[key].split())
            break
    shape = (xyz[2], xyz[1], xyz[0])
    nbytes = int(np.prod(shape, dtype=np.int64)) * dtype.itemsize
    datafile = f["ElementDataFile"]
    compressed = f.get("CompressedData", "False").lower() == "true"
    info = {"format": "metaimage", "compressed": compressed, "detached": datafile != "LOCAL"}
    if datafile.split()[0] == "LIST" or len(datafile.split()) > 1:
        # multi-file slice layouts: rare, let VTK's MetaIO handle them (reads into memory)
        import vtk
        from vtk.util import numpy_support as ns

        r = vtk.vtkMetaImageReader()
        r.SetFileName(str(path))
        r.Update()
        img = r.GetOutput()
        if img.GetPointData().GetScalars() is None:
            raise InputError(f"{what}: VTK could not read the multi-file MetaImage data ({datafile})")
        x, y, z = img.GetDimensions()
        data = ns.vtk_to_numpy(img.GetPointData().GetScalars()).reshape(z, y, x)
        info["reader"] = "vtkMetaImageReader"
        return _native(data), tuple(float(s) for s in img.GetSpacing()), info
    dpath = path if datafile == "LOCAL" else (path.parent / datafile if not os.path.isabs(datafile) else Path(datafile))
    if not dpath.is_file():
        raise InputError(f"{what}: MetaImage data file {dpath} not found (ElementDataFile = {datafile})")
    offset = header_end if datafile == "LOCAL" else 0
    header_size = int(f.get("HeaderSize", "0"))
    if compressed:
        with open(dpath, "rb") as fh:
            fh.seek(offset)
            try:
                raw = zlib.decompress(fh.read())
            except zlib.error as err:
                raise InputError(f"{what}: corrupt zlib data in {dpath} ({err})") from None
        if len(raw) < nbytes:
            raise InputError(f"{what}: decompressed data has {len(raw)} bytes but DimSize x {etype} need {nbytes} bytes")
        data = np.frombuffer(raw, dtype, count=nbytes // dtype.itemsize, offset=len(raw) - nbytes if header_size == -1 else max(header_size, 0))
        data = data.reshape(shape)
    else:
        if header_size == -1:  # data are the last bytes of the file
            offset = dpath.stat().st_size - nbytes
        else:
            offset += header_size
        data = _memmap(dpath, dtype, shape, max(offset, 0), what)
    return _native(data), spacing, info


def read_nifti(path: Path, what: str | None = None):
    """NIfTI via nibabel: voxel axes (i, j, k) -> (x, y, z); the affine's rotation is not applied."""
    import nibabel as nib

    what = what or str(path)
    try:
        img = nib.load(str(path))
        proxy = img.dataobj
        data = np.asanyarray(proxy)  # a memmap for unscaled .nii; scaled data becomes float
    except Exception as err:  # nibabel raises many types for bad files
        raise InputError(f"{what}: cannot read NIfTI file ({type(err).__name__}: {err})") from None
    data = _as_zyx(data, what)
    # NIfTI stores i fastest: the (X, Y, Z) Fortran array is exactly a C-order (Z, Y, X) array
    data = data.T
    if not data.flags.c_contiguous:
        data = np.ascontiguousarray(data)
    zooms = img.header.get_zooms()[:3]
    slope, inter = getattr(proxy, "slope", 1.0), getattr(proxy, "inter", 0.0)
    info = {
        "format": "nifti",
        "axcodes": "".join(nib.aff2axcodes(img.affine)),
        "spatial_unit": str(img.header.get_xyzt_units()[0]),
        "scaled": bool(not (slope == 1.0 and inter == 0.0)),
    }
    return _native(data), tuple(float(z) for z in zooms), info


_READERS = {
    ".vti": read_vti, ".nrrd": read_nrrd, ".nhdr": read_nrrd, ".mha": read_metaimage,
    ".mhd": read_metaimage, ".nii": read_nifti, ".nii.gz": read_nifti,
}


def read_volume(path: str | os.PathLike, *, dims=None, dtype=None, spacing=None, name: str | None = None,
                what: str | None = None) -> tuple[np.ndarray, tuple[float, float, float], dict[str, Any]]:
    """Read any supported file as ``(data (Z, Y, X), spacing (sx, sy, sz), info)``.

    Args:
        path: the file; the extension picks the reader (:data:`SUPPORTED_EXTENSIONS`).
        dims: ``(x, y, z)``; ``.raw`` only (overrides the file name).
        dtype: one of :data:`RAW_DTYPES`; ``.raw`` only (overrides the file name).
        spacing: ``(sx, sy, sz)`` (or one number) overriding the file's spacing; default is the
            header's spacing, or ``(1, 1, 1)`` for files without one (``.raw``).
        name: volume name recorded in ``info["name"]`` (default: derived from the file name).
        what: how errors name the file (default: the path).

    Returns:
        ``data``: native-dtype ``(Z, Y, X)`` array, a read-only ``np.memmap`` when the file allows
        it; ``spacing``; ``info`` (plain data: format, where dims/spacing came from, ...).

    Example:
        >>> data, spacing, info = read_volume("mri_head_128x128x84_uint8.raw")  # doctest: +SKIP
        >>> data.shape, spacing, info["format"]                                 # doctest: +SKIP
        ((84, 128, 128), (1.0, 1.0, 1.0), 'raw')
    """
    path = Path(path).expanduser()
    what = what or str(path)
    ext = _extension(path)
    if ext not in SUPPORTED_EXTENSIONS:
        raise InputError(f"{what}: unknown extension '{ext}', expected one of {' '.join(SUPPORTED_EXTENSIONS)}")
    if not path.is_file():
        raise InputError(f"{what}: file not found")
    if ext != ".raw" and (dims is not None or dtype is not None):
        raise InputError(f"{what}: scene.volume.dims/dtype apply to .raw files only; '{ext}' files store their own")
    if ext == ".raw":
        data, file_spacing, info = read_raw(path, dims, dtype, what)
    else:
        data, file_spacing, info = _READERS[ext](path, what)
    if spacing is not None:
        sp = _check_spacing(spacing, "scene.volume.spacing")
        info["spacing_from"] = "config"
    elif file_spacing is not None:
        sp = _check_spacing(file_spacing, f"{what}: spacing in file header")
        info["spacing_from"] = "header"
    else:
        sp = (1.0, 1.0, 1.0)
        info["spacing_from"] = "default"
    if min(data.shape) < 2:
        raise InputError(f"{what}: every axis needs at least 2 voxels, got (x, y, z)={data.shape[::-1]}")
    if name is None:
        parsed = parse_raw_name(path) if ext == ".raw" else None
        name = parsed["name"] if parsed else path.name[: len(path.name) - len(ext)]
    info["name"] = str(name)
    info["dims_xyz"] = [int(d) for d in data.shape[::-1]]
    info["dtype"] = str(data.dtype)
    return data, sp, info


# ---------------------------------------------------------------------------------------------
# value statistics (chunked: never a float copy of a whole memory-mapped file)
# ---------------------------------------------------------------------------------------------
def _slabs(data: np.ndarray, chunk_voxels: int = _CHUNK_VOXELS):
    """Yield ``(z0, slab)`` z-slabs of about ``chunk_voxels`` voxels (views, no copies)."""
    per_slice = int(data.shape[1]) * int(data.shape[2])
    step = max(1, chunk_voxels // max(per_slice, 1))
    for z0 in range(0, data.shape[0], step):
        yield z0, data[z0:z0 + step]


def scan_values(data: np.ndarray, chunk_voxels: int = _CHUNK_VOXELS) -> dict[str, Any]:
    """Finite min/max and the count/first position of NaN/Inf voxels, slab by slab.

    Args:
        data: ``(Z, Y, X)`` array of any dtype (may be a memmap).

    Returns:
        ``{"min", "max"}`` over finite voxels (``None`` if there are none), ``"nonfinite"`` count,
        ``"first_nonfinite_xyz"`` (or ``None``).

    Example:
        >>> scan_values(np.array([[[1.0, np.nan], [3.0, -2.0]]] * 2))["nonfinite"]
        2
    """
    lo, hi, bad, first = np.inf, -np.inf, 0, None
    is_float = np.issubdtype(data.dtype, np.floating)
    for z0, slab in _slabs(data, chunk_voxels):
        if is_float:
            fin = np.isfinite(slab)
            n_bad = int(fin.size - np.count_nonzero(fin))
            if n_bad:
                if first is None:
                    z, y, x = np.argwhere(~fin)[0]
                    first = (int(x), int(y), int(z + z0))
                bad += n_bad
                vals = slab[fin]
                if vals.size == 0:
                    continue
                lo, hi = min(lo, float(vals.min())), max(hi, float(vals.max()))
                continue
        lo, hi = min(lo, float(slab.min())), max(hi, float(slab.max()))
    return {
        "min": None if lo == np.inf else lo,
        "max": None if hi == -np.inf else hi,
        "nonfinite": bad,
        "first_nonfinite_xyz": first,
    }


def _replace_nonfinite(data: np.ndarray, value: float) -> np.ndarray:
    """Replace NaN/Inf by ``value`` slab by slab; read-only memmaps become copy-on-write maps
    (only the touched pages are copied; the file is never modified)."""
    if not data.flags.writeable:
        if isinstance(data, np.memmap) and data.filename is not None and data.flags.c_contiguous:
            data = np.memmap(data.filename, dtype=data.dtype, mode="c", offset=data.offset, shape=data.shape, order="C")
        else:
            data = np.array(data)
    for _, slab in _slabs(data):
        bad = ~np.isfinite(slab)
        if bad.any():
            slab[bad] = value
    return data


def subsample(data: np.ndarray, max_voxels: int = _PERCENTILE_SAMPLES) -> np.ndarray:
    """A strided (every k-th voxel on each axis) copy of at most about ``max_voxels`` voxels."""
    n = int(np.prod(data.shape, dtype=np.int64))
    k = 1
    while n / k**3 > max_voxels:
        k += 1
    return np.asarray(data[::k, ::k, ::k])


def percentile_range(data: np.ndarray, lo: float, hi: float, max_voxels: int = _PERCENTILE_SAMPLES) -> tuple[float, float, int]:
    """``(p_lo, p_hi, samples)``: percentiles of the finite voxels of a strided subsample."""
    s = subsample(data, max_voxels).reshape(-1)
    if np.issubdtype(s.dtype, np.floating):
        s = s[np.isfinite(s)]
    p = np.percentile(s, [lo, hi])
    return float(p[0]), float(p[1]), int(s.size)


# ---------------------------------------------------------------------------------------------
# the config entry point
# ---------------------------------------------------------------------------------------------
def _get(cfg: Mapping, key: str, default=None):
    try:
        val = cfg.get(key, default)
    except AttributeError:
        val = default
    return default if val is None else val


def _plain(value):
    """OmegaConf containers -> plain Python (lists/dicts), everything else unchanged."""
    try:
        from omegaconf import OmegaConf

        if OmegaConf.is_config(value):
            return OmegaConf.to_container(value, resolve=True)
    except ImportError:  # pragma: no cover - omegaconf is a dependency
        pass
    return value


def _resolve_path(path: str) -> Path:
    """Relative paths are relative to where the user started the command (Hydra may chdir)."""
    try:
        from hydra.utils import to_absolute_path

        return Path(to_absolute_path(str(Path(path).expanduser())))
    except Exception:  # hydra not installed/initialized: plain cwd
        return Path(path).expanduser().resolve()


def finalize_volume(data: np.ndarray, spacing, *, name: str, source: str, info: dict[str, Any] | None = None,
                    clip_percentiles=None, nan_to=None, what: str = "volume") -> Volume:
    """Scan values, handle NaN/Inf, choose the value range, and build the :class:`Volume`.

    Args:
        data: ``(Z, Y, X)`` native-dtype array (memmaps stay memmaps).
        spacing: ``(sx, sy, sz)``.
        clip_percentiles: ``[lo, hi]`` in [0, 100]: value range from these percentiles (of a
            strided subsample of at most ~8M voxels) instead of min/max.
        nan_to: replace NaN/Inf voxels by this value; without it NaN/Inf is an :class:`InputError`.
        what: how errors name the data (file or parameter).

    Returns:
        The Volume, with ``info`` recording ``data_range``, ``value_range_from`` and what was used.
    """
    info = dict(info or {})
    stats = scan_values(data)
    if stats["nonfinite"]:
        if nan_to is None:
            x, y, z = stats["first_nonfinite_xyz"]
            raise InputError(
                f"{what}: {stats['nonfinite']} NaN/Inf voxels (first at x={x}, y={y}, z={z}); "
                f"set scene.volume.nan_to=<value> to replace them"
            )
        try:
            nan_to = float(nan_to)
        except (TypeError, ValueError):
            raise InputError(f"scene.volume.nan_to={nan_to!r}: expected a finite number") from None
        if not np.isfinite(nan_to):
            raise InputError(f"scene.volume.nan_to={nan_to!r}: expected a finite number")
        data = _replace_nonfinite(data, nan_to)
        stats["min"] = nan_to if stats["min"] is None else min(stats["min"], nan_to)
        stats["max"] = nan_to if stats["max"] is None else max(stats["max"], nan_to)
        info["nonfinite_replaced"] = int(stats["nonfinite"])
        info["nan_to"] = nan_to
    vmin, vmax = stats["min"], stats["max"]
    if vmin is None or vmax <= vmin:
        raise InputError(f"{what}: constant volume (every voxel is {vmin}): nothing to render")
    info["data_range"] = [vmin, vmax]
    if clip_percentiles is not None:
        cp = _plain(clip_percentiles)
        try:
            lo, hi = (float(c) for c in cp)
            ok = 0.0 <= lo < hi <= 100.0
        except (TypeError, ValueError):
            ok = False
        if not ok:
            raise InputError(f"scene.volume.clip_percentiles={cp!r}: expected [lo, hi] with 0 <= lo < hi <= 100")
        plo, phi, n = percentile_range(data, lo, hi)
        if not phi > plo:
            raise InputError(
                f"{what}: clip_percentiles [{lo}, {hi}] give a constant range {plo}..{phi}; widen them "
                f"(scene.volume.clip_percentiles) or drop them (data range {vmin}..{vmax})"
            )
        value_range = (plo, phi)
        info.update(value_range_from="percentiles", clip_percentiles=[lo, hi], percentile_samples=n)
    else:
        value_range = (vmin, vmax)
        info["value_range_from"] = "minmax"
    return Volume(data, tuple(spacing), value_range, name, source, info)


def load_volume(cfg: Mapping, prefix: str = "scene.volume") -> Volume:
    """Build the :class:`Volume` described by a ``scene.volume`` config node.

    Keys (``None`` means "not set"; unknown keys are an error, keys starting with ``_`` are ignored):

    * ``kind``: ``"file"`` (default) or ``"procedural"``.
    * ``path``: the file (``kind=file``); relative to the directory the command was started in.
    * ``dims`` ``[x, y, z]`` and ``dtype`` (``.raw`` only): override the file name.
    * ``spacing``: ``[sx, sy, sz]`` (or one number) overriding the file's spacing.
    * ``clip_percentiles``: ``[lo, hi]``: value range from percentiles instead of min/max.
    * ``nan_to``: replace NaN/Inf voxels by this number (otherwise they are an error).
    * ``name``: volume name (default: from the file name / the generator).
    * ``generator``, ``size`` (int or ``[x, y, z]``), ``seed`` (``kind=procedural``).
    * ``stream_to`` (``kind=procedural``): a directory; the volume is streamed there slab by slab
      on every core (:func:`~data_gen.procedural.write_procedural_raw`, reused when its content
      checks out) and memory-mapped, as paper-size volumes must be. ``null``: made in memory.
      Either way the volume's ``source`` is the procedural string, so caches do not depend on it.

    Args:
        cfg: dict or ``DictConfig``.
        prefix: how error messages name the node.

    Returns:
        A Volume: ``data`` (Z, Y, X) native dtype (a read-only memmap for ``.raw`` and other
        uncompressed files), ``spacing``, ``value_range``, ``name``, ``source`` (the absolute path,
        or ``procedural:<gen>?size=x,y,z&seed=s``), ``info`` (provenance, JSON-able).

    Example:
        >>> v = load_volume({"kind": "procedural", "generator": "tiny", "seed": 0})
        >>> v.dims, v.data.dtype.name, v.source
        ((32, 32, 32), 'float32', 'procedural:tiny?size=32,32,32&seed=0')
    """
    if cfg is None:
        raise InputError(f"{prefix}: missing (expected kind=file with a path, or kind=procedural)")
    keys = [str(k) for k in cfg.keys()]
    unknown = [k for k in keys if k not in VOLUME_CONFIG_KEYS and not k.startswith("_")]
    if unknown:
        raise InputError(f"{prefix}: unknown key(s) {', '.join(unknown)}; expected some of {', '.join(VOLUME_CONFIG_KEYS)}")
    kind = str(_get(cfg, "kind", "file")).lower()
    spacing = _plain(_get(cfg, "spacing"))
    clip = _plain(_get(cfg, "clip_percentiles"))
    nan_to = _get(cfg, "nan_to")
    name = _get(cfg, "name")
    if kind == "procedural" and _get(cfg, "stream_to") not in (None, ""):
        return _streamed_procedural(cfg, prefix, spacing, clip, nan_to, name)
    if kind == "procedural":
        from .procedural import make_procedural

        vol = make_procedural(_get(cfg, "generator", ""), _plain(_get(cfg, "size")), _get(cfg, "seed", 0))
        sp = _check_spacing(spacing, f"{prefix}.spacing") if spacing is not None else vol.spacing
        info = dict(vol.info, spacing_from="config" if spacing is not None else "default")
        return finalize_volume(vol.data, sp, name=str(name or vol.name), source=vol.source, info=info,
                               clip_percentiles=clip, nan_to=nan_to, what=f"{prefix} ({vol.source})")
    if kind != "file":
        raise InputError(f"{prefix}.kind={_get(cfg, 'kind')!r}: expected 'file' or 'procedural'")
    raw_path = _get(cfg, "path")
    if raw_path is None or str(raw_path).strip() == "":
        raise InputError(f"{prefix}.path: missing (expected the volume file for kind=file)")
    path = _resolve_path(str(raw_path))
    what = f"{prefix}.path={raw_path}"
    data, sp, info = read_volume(path, dims=_plain(_get(cfg, "dims")), dtype=_get(cfg, "dtype"),
                                 spacing=spacing, name=name, what=what)
    return finalize_volume(data, sp, name=info["name"], source=str(path), info=info,
                           clip_percentiles=clip, nan_to=nan_to, what=what)


def _streamed_procedural(cfg: Mapping, prefix: str, spacing, clip, nan_to, name) -> Volume:
    """A procedural volume streamed to ``<stream_to>/<generator>_XxYxZ_float32.raw`` and memory-mapped."""
    from .procedural import PROCEDURAL_GENERATORS, procedural_source, procedural_spec, write_procedural_raw

    gen, dims, seed = procedural_spec(_get(cfg, "generator", ""), _plain(_get(cfg, "size")), _get(cfg, "seed", 0))
    out = Path(str(_get(cfg, "stream_to"))).expanduser()
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise InputError(f"{prefix}.stream_to={out}: cannot create the directory ({err.strerror})") from None
    path = write_procedural_raw(gen, dims, out, seed=seed, workers=0)
    data = _memmap(path, RAW_DTYPES["float32"], (dims[2], dims[1], dims[0]), 0, f"{prefix}.stream_to ({path})")
    source = procedural_source(gen, dims, seed)
    sp = _check_spacing(spacing, f"{prefix}.spacing") if spacing is not None else (1.0, 1.0, 1.0)
    info = {"generator": gen, "size_xyz": list(dims), "seed": seed, "description": PROCEDURAL_GENERATORS[gen].description,
            "spacing_from": "config" if spacing is not None else "default", "streamed_to": str(path)}
    return finalize_volume(data, sp, name=str(name or gen), source=source, info=info,
                           clip_percentiles=clip, nan_to=nan_to, what=f"{prefix} ({source})")
