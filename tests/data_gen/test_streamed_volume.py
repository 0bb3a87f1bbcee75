"""Procedural volumes streamed to a memory-mapped .raw file (scene.volume.stream_to), checked by content."""
from __future__ import annotations

import numpy as np
import pytest

from imls_lightning.base.errors import InputError
from data_gen.procedural import make_procedural, raw_matches, raw_name, write_procedural_raw
from data_gen.volumes import load_volume


def test_parallel_slabs_equal_the_whole_volume(tmp_path):
    p = write_procedural_raw("flame", (20, 18, 29), tmp_path, seed=2, chunk_z=4, workers=2)
    assert p.name == "flame-seed2_20x18x29_float32.raw"
    assert [f.name for f in tmp_path.iterdir()] == [p.name]
    data = np.fromfile(p, dtype="<f4").reshape(29, 18, 20)
    np.testing.assert_array_equal(data, make_procedural("flame", (20, 18, 29), 2).data)


def test_seed_zero_keeps_the_plain_name_and_seeds_never_share_a_file():
    assert raw_name("flame", (1408, 1080, 1100)) == "flame_1408x1080x1100_float32.raw"
    assert raw_name("flame", 8, seed=1) != raw_name("flame", 8, seed=2)


def test_stream_to_memory_maps_and_keeps_the_procedural_source(tmp_path):
    cfg = {"kind": "procedural", "generator": "tiny", "size": [24, 20, 16], "seed": 3, "stream_to": str(tmp_path / "vols")}
    vol = load_volume(cfg)
    mem = load_volume({k: v for k, v in cfg.items() if k != "stream_to"})
    assert isinstance(vol.data, np.memmap)
    assert vol.source == mem.source == "procedural:tiny?size=24,20,16&seed=3"
    np.testing.assert_array_equal(np.asarray(vol.data), mem.data)
    assert vol.value_range == mem.value_range
    assert vol.info["streamed_to"].endswith("tiny-seed3_24x20x16_float32.raw")


def test_a_file_that_does_not_check_out_is_regenerated(tmp_path, capsys):
    p = write_procedural_raw("tiny", 16, tmp_path, seed=0)
    assert raw_matches("tiny", 16, p, seed=0) and not raw_matches("tiny", 16, p, seed=1)
    data = np.fromfile(p, dtype="<f4")
    data[16 * 16 * 8 + 5] += 1.0                      # one voxel of the middle slice changed
    data.tofile(p)
    assert not raw_matches("tiny", 16, p, seed=0)
    write_procedural_raw("tiny", 16, tmp_path, seed=0)
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "regenerating" in err[0] and str(p) in err[0]
    np.testing.assert_array_equal(np.fromfile(p, dtype="<f4").reshape(16, 16, 16), make_procedural("tiny", 16, 0).data)
    # a whole file is reused as it is
    mtime = p.stat().st_mtime_ns
    write_procedural_raw("tiny", 16, tmp_path, seed=0)
    assert p.stat().st_mtime_ns == mtime and capsys.readouterr().err == ""


def test_a_truncated_file_is_regenerated(tmp_path):
    p = write_procedural_raw("tiny", 12, tmp_path)
    p.write_bytes(p.read_bytes()[:100])
    assert write_procedural_raw("tiny", 12, tmp_path) == p and p.stat().st_size == 12 ** 3 * 4


@pytest.mark.parametrize("workers", [-1, "x", 1.5])
def test_exception_bad_workers(tmp_path, workers):
    with pytest.raises(InputError, match="workers=") as e:
        write_procedural_raw("tiny", 8, tmp_path, workers=workers)
    assert "\n" not in str(e.value)


def test_exception_stream_to_not_a_directory(tmp_path):
    f = tmp_path / "file"
    f.write_text("x")
    with pytest.raises(InputError, match="scene.volume.stream_to") as e:
        load_volume({"kind": "procedural", "generator": "tiny", "size": 8, "stream_to": str(f)})
    assert "\n" not in str(e.value)
