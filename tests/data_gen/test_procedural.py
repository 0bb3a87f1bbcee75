"""Procedural volumes: determinism, seeds, character, slab streaming, regeneration, errors."""
from __future__ import annotations

import time
import tracemalloc

import numpy as np
import pytest

from imls_lightning.base.errors import InputError
from data_gen.procedural import (
    PROCEDURAL_GENERATORS,
    RT_PLUMES,
    _cell_hash,
    _voxel,
    from_source,
    grid_axes,
    make_procedural,
    parse_procedural_source,
    plume_lattice,
    write_procedural_raw,
)
from data_gen.volumes import load_volume

GENERATORS = list(PROCEDURAL_GENERATORS)
SMALL = 24  # keeps every test well under a second


@pytest.mark.parametrize("gen", GENERATORS)
def test_smoke_deterministic_finite_nonconstant(gen):
    a = make_procedural(gen, SMALL, seed=5)
    b = make_procedural(gen, SMALL, seed=5)
    assert a.data.dtype == np.float32 and a.data.shape == (SMALL,) * 3
    np.testing.assert_array_equal(a.data, b.data)
    assert np.isfinite(a.data).all()
    assert a.value_range[1] > a.value_range[0] and a.data.std() > 0.05 * (a.value_range[1] - a.value_range[0])
    assert a.source == f"procedural:{gen}?size={SMALL},{SMALL},{SMALL}&seed=5"


@pytest.mark.parametrize("gen", GENERATORS)
def test_seeds_give_distinct_volumes(gen):
    a, b = make_procedural(gen, SMALL, 0).data, make_procedural(gen, SMALL, 1).data
    # against the content's own spread (a small object in empty space, like seed_shell's, differs in few voxels)
    assert np.abs(a - b).mean() > 0.1 * np.abs(a - np.median(a)).mean()


#: generators of the paper's regime: 512^3 by default, far too large to build in CI
PAPER = [g for g in GENERATORS if max(PROCEDURAL_GENERATORS[g].default_size) >= 256]


@pytest.mark.parametrize("gen", GENERATORS)
def test_default_size_and_speed(gen):
    g = PROCEDURAL_GENERATORS[gen]
    if gen in PAPER:
        # the default is checked without generating it: one z-slice of the default dims
        assert g.default_size == (512, 512, 512)
        X, Y, Z = g.default_size
        s = g.fn(g.default_size, 0, Z // 2, Z // 2 + 1)
        assert s.shape == (1, Y, X) and s.dtype == np.float32 and np.isfinite(s).all()
    else:
        v = make_procedural(gen)
        assert v.dims == g.default_size
        if gen == "tiny":
            assert v.dims == (32, 32, 32)
        else:
            assert all(64 <= d <= 96 for d in v.dims)
    t = time.perf_counter()
    make_procedural(gen, 64, seed=1)
    assert time.perf_counter() - t < 1.0  # the brief: < 1 s for 64^3 on one core


@pytest.mark.parametrize("gen", GENERATORS)
def test_slabs_match_whole_volume(gen):
    """A z-slab is bit-identical to the same rows of the whole volume (what streaming relies on)."""
    dims = (20, 16, 23)
    g = PROCEDURAL_GENERATORS[gen].fn
    whole = g(dims, 3, 0, dims[2])
    assert whole.shape == (23, 16, 20)
    parts = np.concatenate([g(dims, 3, z0, min(23, z0 + 7)) for z0 in range(0, 23, 7)])
    np.testing.assert_array_equal(parts, whole)


def test_paper_generators_are_registered():
    assert {"rayleigh_taylor", "flame_sheets", "seed_shell", "rt_plumes"} <= set(PAPER)


@pytest.mark.parametrize("gen", ["rayleigh_taylor", "flame_sheets", "seed_shell", "rt_plumes"])
def test_paper_generator_slab_seed_determinism(gen):
    """At 40^3: a middle slab is bit-identical to the same rows of the whole volume; the same
    seed gives the same bits, another seed another volume; all values finite."""
    g = PROCEDURAL_GENERATORS[gen].fn
    dims = (40, 40, 40)
    whole = g(dims, 2, 0, 40)
    assert whole.shape == (40, 40, 40) and whole.dtype == np.float32 and np.isfinite(whole).all()
    np.testing.assert_array_equal(g(dims, 2, 13, 27), whole[13:27])
    np.testing.assert_array_equal(g(dims, 2, 0, 40), whole)
    other = g(dims, 3, 0, 40)
    assert np.abs(other - whole).mean() > 0.005 * (whole.max() - whole.min())


def test_rayleigh_taylor_heavy_over_light_with_sharp_interfaces():
    d = make_procedural("rayleigh_taylor", 64, seed=0).data
    assert abs(d.min() - 1.0) < 0.01 and abs(d.max() - 3.0) < 0.01
    assert d[-4:].mean() > 2.95 and d[:4].mean() < 1.05  # heavy (3) on top (+z) of light (1)
    mid = d[24:40]
    assert (mid > 2.5).mean() > 0.15 and (mid < 1.5).mean() > 0.15  # both fluids interpenetrate
    # sharp interfaces: even inside the mixing zone few voxels hold intermediate densities
    assert ((mid > 1.3) & (mid < 2.7)).mean() < 0.35
    # coherent, not speckle: a voxel mostly has the same fluid as its neighbour
    heavy = mid > 2.0
    assert (heavy[:, :, 1:] != heavy[:, :, :-1]).mean() < 0.2


def _runs(mask: np.ndarray) -> list[int]:
    """Lengths of the runs of True in a 1D mask."""
    edges = np.diff(np.concatenate([[0], mask.astype(np.int8), [0]]))
    return (np.flatnonzero(edges == -1) - np.flatnonzero(edges == 1)).tolist()


def test_flame_sheets_thin_sheets_and_empty_surroundings():
    d = make_procedural("flame_sheets", 96, seed=0).data
    vmax = d.max()
    sides = np.concatenate([d[:, :, :4].ravel(), d[:, :, -4:].ravel(), d[:, :4].ravel(), d[:, -4:].ravel()])
    assert sides.max() < 0.01 * vmax  # empty space around the flame
    assert d[-3:].max() < 0.1 * vmax  # pockets above the tip fade out before the top
    assert (d > 0.1 * vmax).mean() < 0.15  # thin sheets: most of the box and of the flame is empty
    # along rays through the flame at a third of its height, the sheets are crossed in short runs: a 2.5-voxel
    # Gaussian profile is 4.8 voxels wide above 0.4 of its peak (grazing crossings of the folds are longer)
    runs = [r for j in range(40, 56, 3) for r in _runs(d[32, j] > 0.4 * vmax)]
    assert len(runs) >= 6 and np.median(runs) <= 7 and np.mean(np.array(runs) <= 9) >= 0.8


def test_seed_shell_husk_with_separate_spines_and_air_around():
    """At its real size (one mid-height slice and the end slices of the 512^3 volume: a slab is
    bit-identical to the whole volume's rows): a shell ~6 voxels thick under spines that stand apart
    with air between them, and air around the specimen."""
    dims = (512, 512, 512)
    g = PROCEDURAL_GENERATORS["seed_shell"].fn
    assert g(dims, 0, 0, 1).max() < 0.01 and g(dims, 0, 511, 512).max() < 0.01  # air below and above
    d = g(dims, 0, 256, 257)[0]
    assert d.min() >= 0.0 and d.max() <= 1.0 and d[:24, :24].max() < 0.01 and d[-24:, -24:].max() < 0.01
    shell, spines = [], 0
    for a in np.linspace(0, 2 * np.pi, 64, endpoint=False):  # rays from the axis outward
        r = np.arange(250)
        ray = d[np.round(255.5 + r * np.sin(a)).astype(int), np.round(255.5 + r * np.cos(a)).astype(int)]
        runs = _runs(ray > 0.45)
        assert runs, "no shell on the ray"
        shell.append(runs[0])
        spines += len(runs) > 1
    # the first crossing is the shell (longer where a spine's base continues it); 2.5-voxel soft edges
    assert 4 <= np.median(shell) <= 8 and max(shell) <= 12
    # spines: some rays meet one beyond the shell, most pass between them (separate lines, not a coat)
    assert 8 <= spines <= 48


def _one_plume(lean=(0.0, 0.0, 0.0, 0.0), cell=0.5, salt=7):
    """The plume of cell (2, 2) of ``plume_lattice``'s lattice: its axis at the root, its reach (the direct formulas)."""
    i = j = np.array([2.0], np.float32)
    xc = -1.0 + (2 + 0.5 + 0.3 * (float(_cell_hash(i, j, salt)[0]) - 0.5)) * cell
    yc = -1.0 + (2 + 0.5 + 0.3 * (float(_cell_hash(i, j, salt + 1)[0]) - 0.5)) * cell
    reach = 0.2 + 0.2 * float(_cell_hash(i, j, salt + 2)[0])

    def sdf(x, y, depth):
        a = np.float32
        return float(plume_lattice(np.full((1, 1, 1), x, a), np.full((1, 1, 1), y, a), np.full((1, 1, 1), depth, a),
                                   tuple(np.float32(v) for v in lean), cell=cell, salt=salt, radius=(0.06, 0.03),
                                   length=(0.2, 0.4), cap=(0.09, 0.04), presence=1.0)[0, 0, 0])
    return xc, yc, reach, sdf


def test_plume_lattice_signed_distance_against_direct_geometry():
    """A plume tapers linearly from its root radius to its tip radius, ends in an ellipsoidal cap, and leans as
    ``l d + c d^2``: the signed distance at points whose distance follows from that geometry directly."""
    xc, yc, reach, sdf = _one_plume()
    for t in (0.1, 0.5, 0.9):
        r, d = 0.06 + (0.03 - 0.06) * t, t * reach
        # on the axis: the nearest of the stem's wall, its root plane, its end, and the cap's pole
        stem = max(-r, -d, d - reach)
        assert sdf(xc, yc, d) == pytest.approx(min(stem, abs(d - reach) - 0.04), abs=1e-5)
    for t in (0.3, 0.5):
        r = 0.06 + (0.03 - 0.06) * t
        # beside the stem, outside it: the lateral gap (the cap lies deeper, farther off)
        assert sdf(xc + r + 0.02, yc, t * reach) == pytest.approx(0.02, abs=1e-5)
    assert sdf(xc, yc, reach) == pytest.approx(-0.04, abs=1e-5)         # the cap's centre: minus its half height
    assert sdf(xc + 0.08, yc, reach) < 0 < sdf(xc + 0.10, yc, reach)    # the cap is 0.09 wide, wider than the stem
    assert sdf(xc, yc, reach + 0.05) > 0 and sdf(xc, yc, -0.01) > 0    # nothing beyond the cap or above the root
    # a lean: at depth d the axis has moved by l d + c d^2
    lx, cx, d = 0.3, 0.5, 0.7 * reach
    xl, yl, reach_l, lean = _one_plume((lx, 0.0, cx, 0.0))
    assert reach_l == reach
    assert lean(xl + lx * d + cx * d * d, yl, d) == pytest.approx(sdf(xc, yc, d), abs=1e-5)
    # absent plumes (presence 0) are far outside everywhere
    none = plume_lattice(*(np.zeros((1, 1, 1), np.float32),) * 3, (np.float32(0),) * 4, cell=0.5, salt=7,
                         radius=(0.06, 0.03), length=(0.2, 0.4), cap=(0.09, 0.04), presence=0.0)
    assert float(none[0, 0, 0]) == 1.0


def test_rt_plumes_caps_fit_their_cells():
    """A plume's widest part plus its cell's jitter stays inside its cell, or a neighbour's lookup would cut it."""
    for name in ("spikes", "fine_spikes", "bubbles"):
        cell, radius, _, cap, _ = RT_PLUMES[name]
        assert max(radius + (cap[0],)) + 0.15 * cell < 0.5 * cell, name


def test_rt_plumes_heavy_over_light_with_separate_spikes_below():
    """At its real size (single z-slices of the 512^3 volume: a slab is bit-identical to the whole volume's rows):
    heavy fluid (3) on top, light (1) below, and under the interface spikes of heavy fluid that stand apart,
    a few voxels thick, with light fluid between them."""
    dims = (512, 512, 512)
    g = PROCEDURAL_GENERATORS["rt_plumes"].fn
    top, bottom = g(dims, 0, 511, 512)[0], g(dims, 0, 0, 1)[0]
    assert top.min() > 2.9 and bottom.max() < 1.1
    below = g(dims, 0, 200, 201)[0]  # about 0.2 under the interface's mean height
    heavy = below > 2.0
    assert 0.01 < heavy.mean() < 0.25  # mostly light fluid, crossed by spikes
    runs = [r for row in heavy[::4] for r in _runs(row)]
    assert len(runs) >= 150  # many separate spikes along the rows
    assert 3 <= np.median(runs) <= 8 and np.percentile(runs, 90) <= 14  # a few voxels thick (caps up to 12 across)
    assert 1.0 <= below.min() and below.max() <= 3.0 and np.isfinite(below).all()


def test_marschner_lobb_against_direct_formula():
    v = make_procedural("marschner_lobb", 41, seed=0)
    x, y, z, _ = grid_axes((41, 41, 41))
    assert x[0] == -1.0 and x[-1] == 1.0  # the classic domain [-1, 1]^3
    fm, alpha = 6.0, 0.25
    for (i, j, k) in [(0, 0, 0), (20, 20, 20), (3, 37, 11), (40, 5, 29)]:
        r = np.hypot(x[i], y[j])
        rho_r = np.cos(2 * np.pi * fm * np.cos(np.pi * r / 2))
        ref = (1 - np.sin(np.pi * z[k] / 2) + alpha * (1 + rho_r)) / (2 * (1 + alpha))
        assert v.data[k, j, i] == pytest.approx(ref, abs=2e-5)
    assert 0.0 <= v.data.min() and v.data.max() <= 1.0


def test_mixing_layer_heavy_over_light_and_fills_box():
    d = make_procedural("mixing_layer", 48, seed=0).data
    assert d[-5:].mean() > 2.6 and d[:5].mean() < 1.4  # heavy (3) on top (+z) of light (1)
    mid = d[d.shape[0] // 2]
    assert (mid > 2.5).mean() > 0.1 and (mid < 1.5).mean() > 0.1  # both fluids interpenetrate mid-box
    # structure across the whole box: each xy quadrant varies (not a flat layer in one corner)
    for qy in (slice(0, 24), slice(24, 48)):
        for qx in (slice(0, 24), slice(24, 48)):
            assert d[:, qy, qx].std() > 0.5


def test_flame_is_compact_with_empty_surroundings():
    v = make_procedural("flame")
    d = v.data
    vmax = d.max()
    border = np.concatenate([d[:, :, :4].ravel(), d[:, :, -4:].ravel(), d[:, :4].ravel(), d[:, -4:].ravel(), d[-3:].ravel()])
    assert border.max() < 0.05 * vmax
    assert (d > 0.1 * vmax).mean() < 0.25  # most of the box is empty
    Z = d.shape[0]
    assert d[Z // 3, d.shape[1] // 2 - 3: d.shape[1] // 2 + 3, d.shape[2] // 2 - 3: d.shape[2] // 2 + 3].mean() > 0.3 * vmax


def test_tiny_has_visible_structure():
    d = make_procedural("tiny").data
    frac = (d > 0.5 * d.max()).mean()
    assert 0.005 < frac < 0.5


def test_generators_have_distinct_character():
    """Share of near-empty voxels and of voxels near the top of the range differ by generator."""
    stats = {}
    for gen in GENERATORS:
        d = make_procedural(gen, 32, 0).data
        n = (d - d.min()) / (d.max() - d.min())
        stats[gen] = ((n < 0.05).mean(), (n > 0.5).mean())
    assert stats["flame"][0] > 0.6  # compact: mostly empty
    assert stats["mixing_layer"][0] < 0.1 and stats["mixing_layer"][1] > 0.3  # fills the box
    assert stats["tiny"][1] < 0.1
    assert 0.3 < stats["marschner_lobb"][1] < 0.7


def test_source_round_trip():
    v = make_procedural("flame", [24, 20, 32], seed=7)
    assert parse_procedural_source(v.source) == ("flame", (24, 20, 32), 7)
    np.testing.assert_array_equal(from_source(v.source).data, v.data)


def test_write_procedural_raw_streams_and_matches(tmp_path):
    p = write_procedural_raw("mixing_layer", (24, 20, 30), tmp_path, seed=4, chunk_z=7)
    assert p.name == "mixing_layer-seed4_24x20x30_float32.raw" and p.parent == tmp_path  # the seed is in the name
    assert [f.name for f in tmp_path.iterdir()] == [p.name]  # no temporary file left behind
    vol = load_volume({"kind": "file", "path": str(p)})
    assert isinstance(vol.data, np.memmap)
    np.testing.assert_array_equal(vol.data, make_procedural("mixing_layer", (24, 20, 30), 4).data)
    # an existing complete file is kept; overwrite rewrites it
    mtime = p.stat().st_mtime_ns
    assert write_procedural_raw("mixing_layer", (24, 20, 30), p, seed=4) == p and p.stat().st_mtime_ns == mtime


def test_write_procedural_raw_memory_is_bounded(tmp_path):
    dims = (64, 64, 512)  # 8 MiB of float32
    tracemalloc.start()
    p = write_procedural_raw("flame", dims, tmp_path, seed=0, chunk_z=8)
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    full = 64 * 64 * 512 * 4
    assert p.stat().st_size == full
    assert peak < 0.25 * full, f"peak {peak} bytes for a {full}-byte volume"


def test_write_procedural_raw_is_atomic_on_failure(tmp_path, monkeypatch):
    """A generator failing mid-stream leaves neither the final file nor a temporary one."""
    from data_gen import procedural

    g = procedural.PROCEDURAL_GENERATORS["tiny"]
    calls = []

    def failing(dims, seed, z0, z1):
        calls.append(z0)
        if len(calls) == 2:
            raise RuntimeError("killed")
        return g.fn(dims, seed, z0, z1)

    monkeypatch.setitem(procedural.PROCEDURAL_GENERATORS, "tiny", procedural.ProceduralGenerator("tiny", failing, g.default_size, ""))
    with pytest.raises(RuntimeError):
        write_procedural_raw("tiny", 16, tmp_path, chunk_z=4)
    assert list(tmp_path.iterdir()) == []


def test_exception_unknown_generator():
    with pytest.raises(InputError) as e:
        make_procedural("smoke")
    msg = str(e.value)
    assert "\n" not in msg and "smoke" in msg and all(g in msg for g in GENERATORS)
    with pytest.raises(InputError):
        load_volume({"kind": "procedural", "generator": "smoke"})


@pytest.mark.parametrize("size", [1, [4, 4], [4, 4, 0], "big", 3.5])
def test_exception_bad_size(size):
    with pytest.raises(InputError) as e:
        make_procedural("tiny", size)
    assert "scene.volume.size" in str(e.value)


@pytest.mark.parametrize("seed", [-1, 1.5, "x"])
def test_exception_bad_seed(seed):
    with pytest.raises(InputError) as e:
        make_procedural("tiny", 8, seed)
    assert "scene.volume.seed" in str(e.value)


def test_exception_write_raw_bad_name(tmp_path):
    with pytest.raises(InputError) as e:
        write_procedural_raw("tiny", 8, tmp_path / "tiny_9x9x9_float32.raw")
    assert "tiny_8x8x8_float32.raw" in str(e.value)
