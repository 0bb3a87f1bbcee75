"""Volume readers, normalization, value ranges and every volume-related bad-input error.

Every reader is checked on a small file written *in the test* with the format's own library
(raw bytes, vtkXMLImageDataWriter, pynrrd.write, vtkMetaImageWriter / a hand-written header,
nibabel.save): values, (Z, Y, X) orientation via a marker voxel, and spacing.
"""
from __future__ import annotations

import tracemalloc
from pathlib import Path

import numpy as np
import pytest

from imls_lightning.base.errors import InputError
from imls_lightning.render.volume import Volume
from data_gen.volumes import (
    RAW_DTYPES,
    SUPPORTED_EXTENSIONS,
    load_volume,
    parse_raw_name,
    percentile_range,
    read_volume,
    scan_values,
)

# (X, Y, Z) = (6, 5, 4); marker at voxel (x, y, z) = (4, 1, 2) -> data[2, 1, 4]
DIMS = (6, 5, 4)
MARK_XYZ = (4, 1, 2)
MARK = 120  # fits every dtype (int8 too); other voxels are < 97
SPACING = (0.5, 1.0, 2.0)


def field(dtype=np.int16) -> np.ndarray:
    """(Z, Y, X) field with distinct values and one marker voxel."""
    x, y, z = DIMS
    a = (np.arange(x * y * z) % 97).reshape(z, y, x).astype(dtype)
    a[MARK_XYZ[2], MARK_XYZ[1], MARK_XYZ[0]] = MARK
    return a


def check(vol: Volume, expected: np.ndarray, spacing=SPACING):
    """Values, orientation (marker at its (x, y, z)) and spacing."""
    assert vol.data.shape == expected.shape
    assert vol.dims == DIMS
    np.testing.assert_array_equal(np.asarray(vol.data), expected)
    (z, y, x), = np.argwhere(np.asarray(vol.data) == MARK)
    assert (x, y, z) == MARK_XYZ
    np.testing.assert_allclose(vol.spacing, spacing, rtol=1e-6)
    assert vol.value_range == (float(expected.min()), float(expected.max()))
    assert vol.data.dtype.isnative


def one_line(exc_info) -> str:
    msg = str(exc_info.value)
    assert "\n" not in msg and msg.strip() == msg
    return msg


def write_raw(tmp: Path, a: np.ndarray, name: str | None = None) -> Path:
    z, y, x = a.shape
    p = tmp / (name or f"vol_{x}x{y}x{z}_{a.dtype.name}.raw")
    a.astype(a.dtype.newbyteorder("<")).tofile(p)
    return p


def vtk_image(a: np.ndarray, spacing=SPACING):
    import vtk
    from vtk.util import numpy_support as ns

    img = vtk.vtkImageData()
    z, y, x = a.shape
    img.SetDimensions(x, y, z)
    img.SetSpacing(*spacing)
    arr = ns.numpy_to_vtk(a.reshape(-1), deep=True)
    arr.SetName("density")
    img.GetPointData().SetScalars(arr)
    return img


# ---------------------------------------------------------------------------------------------
# readers (smoke + values + orientation + spacing)
# ---------------------------------------------------------------------------------------------
@pytest.mark.parametrize("dtype", list(RAW_DTYPES))
def test_raw_every_dtype(tmp_path, dtype):
    a = field(RAW_DTYPES[dtype].newbyteorder("="))
    p = write_raw(tmp_path, a, f"my_vol_6x5x4_{dtype}.raw")
    vol = load_volume({"kind": "file", "path": str(p), "spacing": list(SPACING)})
    check(vol, a)
    assert vol.name == "my_vol" and vol.source == str(p.resolve())
    assert vol.info["dims_from"] == "file name" and vol.info["spacing_from"] == "config"


def test_raw_is_memory_mapped_not_copied(tmp_path):
    a = field(np.float32)
    p = write_raw(tmp_path, a)
    vol = load_volume({"path": str(p)})
    assert isinstance(vol.data, np.memmap)
    assert Path(vol.data.filename) == p.resolve() and not vol.data.flags.owndata
    assert not vol.data.flags.writeable  # read-only map: the file can never be modified
    # the flat view the renderers hand to VTK is still the same mapped memory
    assert np.shares_memory(vol.data.reshape(-1), vol.data)


def test_raw_dims_dtype_override(tmp_path):
    a = field(np.uint16)
    p = write_raw(tmp_path, a, "scan.raw")  # no convention in the name
    vol = load_volume({"path": str(p), "dims": [6, 5, 4], "dtype": "uint16", "spacing": list(SPACING), "name": "s"})
    check(vol, a)
    assert vol.name == "s" and vol.info["dims_from"] == "config"
    # config overrides beat what the file name says
    p2 = write_raw(tmp_path, a, "wrong_2x2x2_uint8.raw")
    vol2 = load_volume({"path": str(p2), "dims": [6, 5, 4], "dtype": "uint16", "spacing": 0.5})
    np.testing.assert_array_equal(vol2.data, a)
    assert vol2.spacing == (0.5, 0.5, 0.5)
    # overridden dims that do not match the file size are still caught
    with pytest.raises(InputError) as e:
        load_volume({"path": str(p2), "dims": [6, 5, 5], "dtype": "uint16"})
    assert "240" in one_line(e) and "300" in str(e.value)


def test_parse_raw_name():
    assert parse_raw_name("ct_head_256x256x108_int16.raw") == {"name": "ct_head", "dims": (256, 256, 108), "dtype": "int16"}
    assert parse_raw_name("/a/b/beechnut_1024x1024x1546_uint16.raw")["dims"] == (1024, 1024, 1546)
    assert parse_raw_name("head.raw") is None and parse_raw_name("x_1x2_int8.raw") is None


def test_vti(tmp_path):
    import vtk

    a = field(np.float32)
    w = vtk.vtkXMLImageDataWriter()
    w.SetFileName(str(tmp_path / "v.vti"))
    w.SetInputData(vtk_image(a))
    w.Write()
    vol = load_volume({"path": str(tmp_path / "v.vti")})
    check(vol, a)
    assert vol.info["format"] == "vti" and vol.info["array"] == "density" and vol.name == "v"


@pytest.mark.parametrize("encoding", ["raw", "gzip"])
@pytest.mark.parametrize("detached", [False, True])
def test_nrrd(tmp_path, encoding, detached):
    import nrrd

    a = field(np.int16)
    name = "v.nhdr" if detached else "v.nrrd"
    header = {"encoding": encoding, "spacings": list(SPACING)}
    nrrd.write(str(tmp_path / name), a, header, detached_header=detached, index_order="C")
    if detached:
        assert len(list(tmp_path.iterdir())) == 2  # header + data file
    vol = load_volume({"path": str(tmp_path / name)})
    check(vol, a)
    assert vol.info["detached"] is detached
    # raw-encoded data (attached or detached) is memory-mapped, not read into memory
    assert isinstance(vol.data, np.memmap) == (encoding == "raw")


@pytest.mark.parametrize("damage", ["flip", "truncate"])
def test_exception_corrupt_gzip_nrrd(tmp_path, damage):
    """A gzip NRRD whose data is corrupt ended in a zlib traceback (issue 17, 10)."""
    import nrrd

    rng = np.random.default_rng(0)
    a = rng.integers(0, 1000, size=(8, 9, 10)).astype(np.int16)  # incompressible enough to damage
    path = tmp_path / "v.nrrd"
    nrrd.write(str(path), a, {"encoding": "gzip"}, index_order="C")
    b = bytearray(path.read_bytes())
    if damage == "flip":
        for i in range(len(b) - 300, len(b) - 200):
            b[i] ^= 0x5A
    else:
        b = b[: len(b) - 200]
    path.write_bytes(bytes(b))
    with pytest.raises(InputError, match=r"v.nrrd: cannot read NRRD data") as e:
        load_volume({"path": str(path)})
    assert "\n" not in str(e.value)


def test_nrrd_space_directions_and_big_endian(tmp_path):
    import nrrd

    a = field(np.float32)
    header = {"encoding": "raw", "endian": "big", "space": "left-posterior-superior",
              "space directions": np.diag(SPACING).tolist()}
    nrrd.write(str(tmp_path / "be.nrrd"), a, header, index_order="C")
    vol = load_volume({"path": str(tmp_path / "be.nrrd")})
    check(vol, a)  # spacing = norms of the space directions; values converted to native order


@pytest.mark.parametrize("fname,compress", [("v.mhd", False), ("v.mha", False), ("v.mhd", True), ("v.mha", True)])
def test_metaimage_vtk_written(tmp_path, fname, compress):
    import vtk

    a = field(np.int16)
    w = vtk.vtkMetaImageWriter()
    w.SetFileName(str(tmp_path / fname))
    w.SetCompression(compress)
    w.SetInputData(vtk_image(a))
    w.Write()
    vol = load_volume({"path": str(tmp_path / fname)})
    check(vol, a)
    assert vol.info["compressed"] is compress
    assert isinstance(vol.data, np.memmap) == (not compress)


def test_metaimage_hand_written_big_endian_headersize(tmp_path):
    a = field(np.uint16)
    (tmp_path / "d.bin").write_bytes(b"JUNK" * 4 + a.astype(">u2").tobytes())
    (tmp_path / "v.mhd").write_text(
        "ObjectType = Image\nNDims = 3\nDimSize = 6 5 4\nElementSpacing = 0.5 1 2\n"
        "ElementType = MET_USHORT\nBinaryDataByteOrderMSB = True\nHeaderSize = 16\nElementDataFile = d.bin\n"
    )
    check(load_volume({"path": str(tmp_path / "v.mhd")}), a)


def test_metaimage_list_falls_back_to_vtk(tmp_path):
    a = field(np.int16)
    for k in range(a.shape[0]):
        a[k].tofile(tmp_path / f"s{k}.raw")
    files = "\n".join(f"s{k}.raw" for k in range(a.shape[0]))
    (tmp_path / "v.mhd").write_text(
        "ObjectType = Image\nNDims = 3\nDimSize = 6 5 4\nElementSpacing = 0.5 1 2\n"
        f"ElementType = MET_SHORT\nElementByteOrderMSB = False\nElementDataFile = LIST 2D\n{files}\n"
    )
    vol = load_volume({"path": str(tmp_path / "v.mhd")})
    check(vol, a)
    assert vol.info["reader"] == "vtkMetaImageReader"


@pytest.mark.parametrize("fname", ["v.nii", "v.nii.gz"])
def test_nifti(tmp_path, fname):
    import nibabel as nib

    a = field(np.float32)
    # nibabel arrays are (X, Y, Z): the test writes the transpose of our (Z, Y, X) field
    img = nib.Nifti1Image(np.ascontiguousarray(a.T), np.diag([*SPACING, 1.0]))
    nib.save(img, str(tmp_path / fname))
    vol = load_volume({"path": str(tmp_path / fname)})
    check(vol, a)
    assert vol.info["spacing_from"] == "header" and vol.name == "v"
    assert vol.data.flags.c_contiguous  # renderers hand the buffer to VTK without a copy
    assert isinstance(vol.data, np.memmap) == (fname == "v.nii")


def test_nifti_scaled_data(tmp_path):
    import nibabel as nib

    a = field(np.int16)
    img = nib.Nifti1Image(np.ascontiguousarray(a.T), np.diag([*SPACING, 1.0]))
    img.header.set_slope_inter(0.5, 10.0)
    nib.save(img, str(tmp_path / "s.nii"))
    vol = load_volume({"path": str(tmp_path / "s.nii")})
    np.testing.assert_allclose(vol.data, a * 0.5 + 10.0)
    assert vol.info["scaled"] is True


# ---------------------------------------------------------------------------------------------
# normalization, value ranges, NaN handling, memory
# ---------------------------------------------------------------------------------------------
def test_normalization_anisotropic_spacing(tmp_path):
    a = np.random.default_rng(0).random((6, 21, 11)).astype(np.float32)  # (X, Y, Z) = (11, 21, 6)
    p = write_raw(tmp_path, a)
    vol = load_volume({"path": str(p), "spacing": [2.0, 0.5, 1.0]})  # physical 20 x 10 x 5
    np.testing.assert_allclose(vol.physical_size, [20, 10, 5])
    np.testing.assert_allclose(vol.half_extent, [1.0, 0.5, 0.25])  # longest axis spans [-1, 1], aspect kept
    np.testing.assert_allclose(vol.origin, [-1.0, -0.5, -0.25])
    np.testing.assert_allclose(vol.bounds, [[-1, 1], [-0.5, 0.5], [-0.25, 0.25]])
    np.testing.assert_allclose(vol.normalized_spacing, [0.2, 0.05, 0.1])
    last = vol.origin + (np.array(vol.dims) - 1) * vol.normalized_spacing
    np.testing.assert_allclose(last, vol.half_extent)
    assert vol.normalize(np.array([vol.value_range[0], vol.value_range[1]])).tolist() == [0.0, 1.0]


def test_percentile_clipping_against_numpy(tmp_path):
    a = np.random.default_rng(1).normal(size=(20, 30, 40)).astype(np.float32)
    a[0, 0, 0], a[1, 1, 1] = 1e6, -1e6  # outliers that would squash min/max
    vol = load_volume({"path": str(write_raw(tmp_path, a)), "clip_percentiles": [0.5, 99.5]})
    lo, hi = np.percentile(a, [0.5, 99.5])
    np.testing.assert_allclose(vol.value_range, (lo, hi), rtol=1e-6)
    assert vol.info["value_range_from"] == "percentiles" and vol.info["clip_percentiles"] == [0.5, 99.5]
    assert vol.info["data_range"] == [-1e6, 1e6]
    plain = load_volume({"path": str(write_raw(tmp_path, a))})
    assert plain.value_range == (-1e6, 1e6) and plain.info["value_range_from"] == "minmax"


def test_percentiles_on_strided_subsample():
    a = np.random.default_rng(2).random((64, 64, 64)).astype(np.float32)
    lo, hi, n = percentile_range(a, 5, 95, max_voxels=5000)
    assert n <= 5000 and n > 1000
    assert abs(lo - 0.05) < 0.02 and abs(hi - 0.95) < 0.02  # uniform data: true percentiles known


def test_scan_values_chunked_against_numpy():
    a = np.random.default_rng(3).normal(size=(37, 11, 13))
    a[5, 2, 3], a[30, 0, 1] = np.nan, -np.inf
    s = scan_values(a, chunk_voxels=100)  # many slabs
    fin = a[np.isfinite(a)]
    assert (s["min"], s["max"], s["nonfinite"], s["first_nonfinite_xyz"]) == (fin.min(), fin.max(), 2, (3, 2, 5))


def test_value_scan_does_not_copy_the_volume(tmp_path):
    a = np.random.default_rng(4).random((128, 128, 128), dtype=np.float32)  # 8 MiB file
    p = write_raw(tmp_path, a)
    del a
    tracemalloc.start()
    vol = load_volume({"path": str(p)})
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    assert isinstance(vol.data, np.memmap)
    assert peak < 0.35 * p.stat().st_size, f"peak {peak} bytes while scanning a {p.stat().st_size}-byte file"


def test_nan_to_replaces_without_touching_file(tmp_path):
    a = field(np.float32)
    a[0, 0, 0], a[1, 2, 3] = np.nan, np.inf
    p = write_raw(tmp_path, a)
    vol = load_volume({"path": str(p), "nan_to": -5.0})
    assert np.isfinite(vol.data).all() and vol.data[0, 0, 0] == -5.0 and vol.data[1, 2, 3] == -5.0
    assert vol.value_range == (-5.0, float(MARK)) and vol.info["nonfinite_replaced"] == 2
    assert isinstance(vol.data, np.memmap)  # copy-on-write map, still no full copy
    assert np.isnan(np.fromfile(p, np.float32)[0])  # the file itself is unchanged


def test_procedural_through_load_volume():
    vol = load_volume({"kind": "procedural", "generator": "tiny", "seed": 2, "size": [32, 24, 16],
                       "spacing": [1, 1, 2], "clip_percentiles": [1, 99], "path": None})
    assert vol.dims == (32, 24, 16) and vol.spacing == (1.0, 1.0, 2.0)
    assert vol.source == "procedural:tiny?size=32,24,16&seed=2" and vol.info["generator"] == "tiny"
    assert vol.info["value_range_from"] == "percentiles"


def test_load_volume_accepts_dictconfig(tmp_path):
    from omegaconf import OmegaConf

    a = field(np.int16)
    cfg = OmegaConf.create({"kind": "file", "path": str(write_raw(tmp_path, a)), "spacing": list(SPACING),
                            "clip_percentiles": None, "nan_to": None, "dims": None, "dtype": None, "name": None,
                            "generator": None, "size": None, "seed": None})
    check(load_volume(cfg), a)


# ---------------------------------------------------------------------------------------------
# bad input: one line, naming the file/parameter and what was expected
# ---------------------------------------------------------------------------------------------
def test_exception_missing_file(tmp_path):
    with pytest.raises(InputError) as e:
        load_volume({"kind": "file", "path": str(tmp_path / "nope_2x2x2_uint8.raw")})
    assert "nope_2x2x2_uint8.raw" in one_line(e) and "not found" in str(e.value)


@pytest.mark.parametrize("name, size, said", [
    ("v_10x10x10_int16.raw", 1998, ["1998", "2000", "10x10x10", "int16"]),       # the file's size against its name
    ("v.xyz", 8, [".xyz", *SUPPORTED_EXTENSIONS]),                               # an unknown extension
    ("head.raw", 8, ["head.raw", "name_XxYxZ_dtype.raw", "dims"]),               # a .raw name without the convention
])
def test_exception_file_that_cannot_be_read(tmp_path, name, size, said):
    p = tmp_path / name
    p.write_bytes(b"\0" * size)
    with pytest.raises(InputError) as e:
        load_volume({"path": str(p)})
    msg = one_line(e)
    assert all(s in msg for s in said), msg


@pytest.mark.parametrize("how", ["name", "config"])
def test_exception_unknown_dtype(tmp_path, how):
    p = tmp_path / ("v_2x2x2_float16.raw" if how == "name" else "v_2x2x2_uint8.raw")
    p.write_bytes(b"\0" * 16)
    cfg = {"path": str(p)} if how == "name" else {"path": str(p), "dtype": "complex64"}
    with pytest.raises(InputError) as e:
        load_volume(cfg)
    msg = one_line(e)
    assert ("float16" if how == "name" else "complex64") in msg and "uint8" in msg and "float64" in msg


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_exception_nonfinite_voxels(tmp_path, bad):
    a = field(np.float32)
    a[2, 3, 1] = bad
    with pytest.raises(InputError) as e:
        load_volume({"path": str(write_raw(tmp_path, a))})
    msg = one_line(e)
    assert "NaN/Inf" in msg and "x=1, y=3, z=2" in msg and "nan_to" in msg


def test_exception_constant_volume(tmp_path):
    p = write_raw(tmp_path, np.full((3, 3, 3), 7, np.uint8))
    with pytest.raises(InputError) as e:
        load_volume({"path": str(p)})
    assert "constant" in one_line(e) and "nothing to render" in str(e.value) and p.name in str(e.value)


@pytest.mark.parametrize("spacing", [[1, 0, 1], [1, -2, 1], [1, 1], "abc", [1, float("nan"), 1]])
def test_exception_bad_spacing(tmp_path, spacing):
    with pytest.raises(InputError) as e:
        load_volume({"path": str(write_raw(tmp_path, field())), "spacing": spacing})
    assert "scene.volume.spacing" in one_line(e) and "positive" in str(e.value)


def test_exception_bad_spacing_in_header(tmp_path):
    import nrrd

    nrrd.write(str(tmp_path / "z.nrrd"), field(), {"spacings": [1.0, 0.0, 1.0]}, index_order="C")
    with pytest.raises(InputError) as e:
        load_volume({"path": str(tmp_path / "z.nrrd")})
    assert "z.nrrd" in one_line(e) and "spacing" in str(e.value)


@pytest.mark.parametrize("cfg,needle", [
    ({"clip_percentiles": [99, 1]}, "clip_percentiles"),
    ({"clip_percentiles": [0, 101]}, "clip_percentiles"),
    ({"nan_tu": 0}, "nan_tu"),
    ({"kind": "url"}, "kind"),
    ({"dims": [6, 5]}, "dims"),
    ({"nan_to": "zero", "_force_nan": True}, "nan_to"),
])
def test_exception_bad_config_values(tmp_path, cfg, needle):
    a = field(np.float32)
    if cfg.pop("_force_nan", False):
        a[0, 0, 0] = np.nan
    with pytest.raises(InputError) as e:
        load_volume({"path": str(write_raw(tmp_path, a)), **cfg})
    assert needle in one_line(e)


def test_exception_dims_on_non_raw(tmp_path):
    import nrrd

    nrrd.write(str(tmp_path / "v.nrrd"), field(), index_order="C")
    with pytest.raises(InputError) as e:
        load_volume({"path": str(tmp_path / "v.nrrd"), "dims": [6, 5, 4]})
    assert ".raw files only" in one_line(e)


def test_exception_missing_path_and_not_3d(tmp_path):
    with pytest.raises(InputError) as e:
        load_volume({"kind": "file"})
    assert "scene.volume.path" in one_line(e)
    import nrrd

    nrrd.write(str(tmp_path / "two.nrrd"), np.zeros((4, 5), np.float32))
    with pytest.raises(InputError) as e:
        read_volume(tmp_path / "two.nrrd")
    assert "3D" in one_line(e)


# ---------------------------------------------------------------------------------------------
# the real volumes of ../shared/volumes (README values)
# ---------------------------------------------------------------------------------------------
REAL = [
    # file, spacing override (None: from the header), dims, dtype, spacing, value range
    ("ct_head_256x256x108_int16.raw", [0.957, 0.957, 1.5], (256, 256, 108), "int16", (0.957, 0.957, 1.5), (-1024, 2986)),
    ("mri_head_128x128x84_uint8.raw", None, (128, 128, 84), "uint8", (1.0, 1.0, 1.0), (0, 202)),
    ("macaque_brain_t1.nii.gz", None, (168, 206, 128), "float32", (0.5, 0.5, 0.5), (0, 383.2)),
    ("density_1jzv_76x96x70_float32.raw", [0.545, 0.545, 0.560], (76, 96, 70), "float32", (0.545, 0.545, 0.56), (-0.99, 9.05)),
]


@pytest.mark.real_volume
@pytest.mark.parametrize("fname,override,dims,dtype,spacing,vrange", REAL, ids=[r[0].split("_")[0] + r[0].split("_")[1] for r in REAL])
def test_real_volumes(volumes_dir, fname, override, dims, dtype, spacing, vrange):
    cfg = {"kind": "file", "path": str(volumes_dir / fname)}
    if override is not None:
        cfg["spacing"] = override
    vol = load_volume(cfg)
    assert vol.dims == dims and vol.data.dtype == np.dtype(dtype)
    np.testing.assert_allclose(vol.spacing, spacing, rtol=1e-6)
    np.testing.assert_allclose(vol.value_range, vrange, atol=0.05 if dtype == "float32" else 0)  # README rounds
    assert max(vol.half_extent) == pytest.approx(1.0)
    if fname.endswith(".raw"):
        assert isinstance(vol.data, np.memmap)
