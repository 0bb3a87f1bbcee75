"""The operating-point record beside an IMS checkpoint is trusted only when it is what the evaluation wrote
(:mod:`imls_lightning.inference.operating_point`): its digest (keyed with the checkpoint's SHA-256), its share against
the share its own search measured at its mean value, and its evaluation's ``summary.json`` when that is at hand. A
record that fails is ignored with one line saying why; the trained mean is used."""
from __future__ import annotations

import json
from pathlib import Path

import pytest

from imls_lightning.base.config import file_hash
from imls_lightning.inference.operating_point import (SEARCH_TOLERANCE, ORPRecord, read_operating_point, record_digest,
                                                      sidecar_path, write_operating_point)

POINTS = [[0.1, 0.08], [0.316, 0.27], [0.562, 0.49], [0.75, 0.66], [0.806, 0.72]]


def _point(**kw) -> ORPRecord:
    base = dict(mean=0.806, lift=False, c_share=0.72, ipr=0.18, epsilon_db=1.0, gap_db=0.4, views=30, scene="tiny",
                points=POINTS, tolerance=SEARCH_TOLERANCE)
    return ORPRecord(**{**base, **kw})


@pytest.fixture
def ckpt(tmp_path) -> Path:
    p = tmp_path / "ims.ckpt"
    p.write_bytes(b"not a real checkpoint: the record names it by its bytes")
    return p


def _read(ckpt, capsys):
    capsys.readouterr()
    point = read_operating_point(ckpt, trained_mean=0.2)
    lines = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
    return point, lines


def _edit(ckpt, reseal: bool = False, **changes) -> None:
    side = sidecar_path(ckpt)
    rec = {**json.loads(side.read_text()), **changes}
    if reseal:
        rec["digest"] = record_digest(rec, file_hash(ckpt, length=64))
    side.write_text(json.dumps(rec))


def _ignored(lines, side, why: str) -> None:
    assert len(lines) == 1, lines
    assert lines[0].startswith(f"[orp] warning: {side} ignored: {why}"), lines
    assert lines[0].endswith("running at the trained mean u = 0.200"), lines


def test_a_record_as_written_is_trusted_and_carries_its_digest(ckpt, capsys):
    point = _point()
    write_operating_point(ckpt, point)
    rec = json.loads(sidecar_path(ckpt).read_text())
    assert rec["digest"] == record_digest(rec, file_hash(ckpt, length=64)) and rec["points"] == POINTS
    got, lines = _read(ckpt, capsys)
    assert got == point and len(lines) == 1 and "running at the evaluation's operating point u = 0.806" in lines[0]


@pytest.mark.parametrize("changes", [{"mean": 0.9, "c_share": 0.05}, {"mean": 0.5}, {"lift": True}, {"epsilon_db": 3.0},
                                     {"points": [[0.9, 0.05]]}])
def test_exception_an_edited_record_is_ignored_in_one_line(ckpt, capsys, changes):
    write_operating_point(ckpt, _point())
    _edit(ckpt, **changes)
    got, lines = _read(ckpt, capsys)
    assert got is None
    _ignored(lines, sidecar_path(ckpt), "its digest does not match its content (it was edited after the evaluation wrote it)")


def test_exception_a_record_without_a_digest_is_not_trusted(ckpt, capsys):
    """Records written before they carried a digest: whether the evaluation wrote them cannot be told."""
    write_operating_point(ckpt, _point())
    side = sidecar_path(ckpt)
    side.write_text(json.dumps({k: v for k, v in json.loads(side.read_text()).items() if k != "digest"}))
    got, lines = _read(ckpt, capsys)
    assert got is None
    _ignored(lines, side, "it carries no digest of its content")
    assert "python -m imls_lightning.evaluate records it again" in lines[0]


def test_exception_a_record_whose_share_is_not_what_its_search_measured_is_ignored(ckpt, capsys):
    """u = 0.9 at 5 % of C, sealed as if the evaluation wrote it: not what its own search measured at that u."""
    write_operating_point(ckpt, _point())
    _edit(ckpt, reseal=True, c_share=0.05)
    got, lines = _read(ckpt, capsys)
    assert got is None
    _ignored(lines, sidecar_path(ckpt), "not self-consistent: 5.0 % of C at u = 0.806, where its search measured 72.0 %")
    _edit(ckpt, reseal=True, c_share=0.72, mean=0.95)
    got, lines = _read(ckpt, capsys)
    assert got is None and "u = 0.950 lies outside the mean values its search tried (0.100-0.806)" in lines[0]
    # within the recorded tolerance: trusted
    _edit(ckpt, reseal=True, mean=0.806, c_share=0.72 * (1 + SEARCH_TOLERANCE / 2))
    got, lines = _read(ckpt, capsys)
    assert got is not None and got.mean == 0.806


def _evaluation(tmp_path, ckpt, **orp) -> Path:
    folder = tmp_path / "eval"
    folder.mkdir(exist_ok=True)
    (folder / "report.md").write_text("# report\n")
    base = {"found": True, "mean": 0.806, "lift": False, "c_share": 0.72, "ipr": 0.18, "epsilon_db": 1.0, "gap_db": 0.4,
            "points": [[u, 0.5, c, 0.9] for u, c in POINTS]}
    (folder / "summary.json").write_text(json.dumps({"orp": {**base, **orp},
                                                     "checkpoints_sha256": {"ims": file_hash(ckpt)}}))
    return folder / "report.md"


def test_a_record_is_cross_checked_with_its_evaluations_summary(ckpt, tmp_path, capsys):
    report = _evaluation(tmp_path, ckpt)
    write_operating_point(ckpt, _point(report=str(report)))
    got, lines = _read(ckpt, capsys)
    assert got is not None and got.mean == 0.806 and "evaluation's operating point" in lines[0]
    summary = report.parent / "summary.json"
    for orp, what in (({"mean": 0.75}, "(mean 0.806 here, 0.75 there)"), ({"c_share": 0.5}, "(c_share 0.72 here, 0.5 there)"),
                      ({"lift": True}, "(lift False here, True there)"), ({"found": False}, "(found True here, False there)")):
        _evaluation(tmp_path, ckpt, **orp)
        got, lines = _read(ckpt, capsys)
        assert got is None
        _ignored(lines, sidecar_path(ckpt), f"it disagrees with its evaluation's {summary} {what}")
    data = json.loads(summary.read_text())
    summary.write_text(json.dumps({**data, "orp": {**data["orp"], "mean": 0.806, "c_share": 0.72, "lift": False, "found": True},
                                   "checkpoints_sha256": {"ims": "0123456789abcdef"}}))
    got, lines = _read(ckpt, capsys)
    assert got is None and "evaluated another IMS checkpoint" in lines[0]
    summary.write_text("{not json")
    got, lines = _read(ckpt, capsys)
    assert got is None and f"its evaluation's {summary} is unreadable" in lines[0]
    summary.unlink()  # not at hand (the evaluation's folder moved or deleted): the record's own checks decide
    got, lines = _read(ckpt, capsys)
    assert got is not None and got.mean == 0.806


def test_a_record_carries_its_decoder_and_the_papers_decoder_is_written_as_before(ckpt, tmp_path, capsys):
    """A point kept with the pull-push fill as decoder is recorded and read with it (its point, its line, checked against
    its evaluation's summary); one with the IMS's own decoder is written without the field, byte for byte what records
    were before it existed, and a record without it reads as the trained decoder. A decoder the product does not know
    is refused in one line."""
    write_operating_point(ckpt, _point())
    assert "decoder" not in json.loads(sidecar_path(ckpt).read_text())
    got, _ = _read(ckpt, capsys)
    assert got.decoder == "trained" and got.point.decoder == "trained"
    report = _evaluation(tmp_path, ckpt, decoder="fill")
    write_operating_point(ckpt, _point(decoder="fill", report=str(report)))
    assert json.loads(sidecar_path(ckpt).read_text())["decoder"] == "fill"
    got, lines = _read(ckpt, capsys)
    assert got.point.decoder == "fill" and "the pull-push fill as decoder" in lines[0]
    _evaluation(tmp_path, ckpt)  # its summary kept the trained decoder: the record disagrees
    got, lines = _read(ckpt, capsys)
    assert got is None and "(decoder fill here, trained there)" in lines[0]
    (report.parent / "summary.json").unlink()
    _edit(ckpt, reseal=True, decoder="refine")
    got, lines = _read(ckpt, capsys)
    assert got is None and "malformed (InputError: decoder='refine': expected 'trained'" in lines[0]


def test_an_explicit_mean_is_not_read_from_the_record(ckpt, capsys):
    from imls_lightning.core.operating_point import OperatingPoint
    from imls_lightning.inference.operating_point import point_to_run

    write_operating_point(ckpt, _point())
    _edit(ckpt, mean=0.9)
    capsys.readouterr()
    assert point_to_run(ckpt, 0.4) == (OperatingPoint(share=0.4), None) and capsys.readouterr().err == ""
    assert point_to_run(ckpt, None)[0] is None and "ignored: its digest does not match" in capsys.readouterr().err


def test_every_consumer_ignores_an_edited_record(tiny_checkpoints, tmp_path, capsys):
    """The renderer (so the desktop viewer), the browser viewer's session and the export load the product through
    ``load_product``, which reads the record through ``read_operating_point``: an edited one is ignored, with one line,
    and the trained mean is used; the adaptive tools' reader says it too."""
    import shutil

    from imls_lightning.adaptive.cli import recorded_bands
    from imls_lightning.inference.checkpoints import load_product
    from imls_lightning.inference.pipeline import IMLSRenderer, NetOptions

    ck = tmp_path / "ims.ckpt"
    shutil.copy(tiny_checkpoints["ims_pim"], ck)
    write_operating_point(ck, _point(lift=True, by_distance={"edges": [3.6], "means": [0.806, 0.5]}))
    _edit(ck, mean=0.9, c_share=0.05)
    capsys.readouterr()
    r = IMLSRenderer.from_checkpoints(str(ck), opts=NetOptions(device="cpu"))
    lines = [ln for ln in capsys.readouterr().err.splitlines() if ln.startswith("[orp]")]
    assert r.record is None and r.mean == pytest.approx(load_product(str(ck), share="trained").nets.trained_mean)
    assert len(lines) == 1 and "ignored: its digest does not match its content" in lines[0]
    assert recorded_bands(str(ck), True) is None
    lines = [ln for ln in capsys.readouterr().err.splitlines() if ln.startswith("[orp]")]
    assert len(lines) == 1 and "ignored: its digest does not match its content" in lines[0]
