"""The completion log and pixel checksums of the cache (:mod:`data_gen.cache_log`)."""
from __future__ import annotations

import os
import zlib

import numpy as np

from data_gen.cache_log import (
    CompletionLog,
    bad_views,
    checked_already,
    forget_checked,
    read_log,
    read_logs,
    remember_checked,
    write_view,
)


def test_log_round_trip_last_line_wins(tmp_path):
    log = CompletionLog(tmp_path / "done.log", fsync=True)
    log.append(0, 1, 0.25)
    log.append(2, 0xFFFFFFFF, 1.5)
    log.append(0, 7, 0.5)
    log.close()
    done, crc, sec = read_log(tmp_path / "done.log", 3)
    assert done.tolist() == [True, False, True]
    assert crc.tolist() == [7, 0, 0xFFFFFFFF] and sec[0] == 0.5 and np.isnan(sec[1])


def test_torn_corrupt_and_out_of_range_lines_are_ignored(tmp_path):
    path = tmp_path / "done.log"
    log = CompletionLog(path, fsync=False)
    log.append(1, 5, 0.1)
    log.append(9, 5, 0.1)  # outside [0, n)
    log.close()
    with open(path, "ab") as f:
        f.write(b"0 00000005 0.1 00000000\n")  # bad line checksum
        f.write(b"2 0000")  # torn by a crash
    assert read_log(path, 3)[0].tolist() == [False, True, False]
    log = CompletionLog(path, fsync=False)  # starts on a fresh line after the torn one
    log.append(2, 3, 0.2)
    log.close()
    assert read_log(path, 3)[0].tolist() == [False, True, True]
    assert read_log(tmp_path / "missing.log", 2)[0].tolist() == [False, False]


def test_shard_logs_are_merged(tmp_path):
    for name, i in (("done.log", 0), ("done-shard-1-of-2.log", 1)):
        log = CompletionLog(tmp_path / name, fsync=False)
        log.append(i, i + 10, 0.1)
        log.close()
    done, crc, _ = read_logs(tmp_path, 2)
    assert done.all() and crc.tolist() == [10, 11]


def test_write_view_in_place_and_bad_views(tmp_path):
    path = tmp_path / "images.npy"
    mm = np.lib.format.open_memmap(path, mode="w+", dtype=np.uint8, shape=(3, 2, 2, 3))
    offset = mm.offset
    del mm
    img = np.arange(12, dtype=np.uint8).reshape(2, 2, 3)
    fd = os.open(path, os.O_WRONLY)
    try:
        crc = write_view(fd, img, 1, offset, fsync=True)
    finally:
        os.close(fd)
    images = np.load(path, mmap_mode="r")
    np.testing.assert_array_equal(images[1], img)
    assert crc == zlib.crc32(img.tobytes()) & 0xFFFFFFFF
    crcs = np.array([0, crc, 123], np.uint32)
    assert bad_views(images, [0, 1, 2], crcs).tolist() == [0, 2]  # zeros do not have CRC 0 or 123


def test_checked_registry_follows_file_changes(tmp_path):
    (tmp_path / "images.npy").write_bytes(b"x")
    forget_checked()
    assert not checked_already(tmp_path)
    remember_checked(tmp_path)
    assert checked_already(tmp_path)
    (tmp_path / "done.log").write_bytes(b"")  # a new file changes the signature
    assert not checked_already(tmp_path)
    remember_checked(tmp_path)
    forget_checked()
    assert not checked_already(tmp_path)
