"""The evaluation's partial results (:mod:`imls_lightning.evaluation.resume`): what is kept, what is trusted on a resume,
and what is dropped (with one line) or started over. The evaluation that resumes end to end: tests/test_evaluate.py."""
from __future__ import annotations

import json

import numpy as np
import pytest

from imls_lightning.evaluation.resume import FORMAT, EvaluationProgress, plain

POSITIONS, TIMED = [0, 4, 8], [0, 8]
POINT = {"orp": {"found": True, "mean": np.float64(0.3), "views": np.int64(40), "points": [(0.3, 0.5, 0.3, 0.9)]},
         "imls_mean": 0.3, "lift": True, "notes": ["a note"]}


def _rows(p: int) -> list[dict]:
    return [{"view": p, "row": 10 + p, "method": m, "psnr": 30.0 + p, "total_ms": None} for m in ("recnn", "imls")]


def _progress(tmp_path, **kw) -> EvaluationProgress:
    return EvaluationProgress(tmp_path, POSITIONS, TIMED, **kw)


def _measured(tmp_path, views=(0, 4)) -> EvaluationProgress:
    pr = _progress(tmp_path)
    pr.save_point(POINT)
    for p in views:
        grid = {"truth": np.full((4, 4, 3), p, np.uint8), "imls_im": np.eye(2, dtype=bool), "none": None} if p == 0 else None
        pr.add_view(p, _rows(p), [{"view": p, "method": "imls", "setting": "share", "value": 0.2}] if p == 4 else [],
                    {"view": p, "cores": 0.01, "seconds": 3.0} if p in TIMED else None, grid)
    return pr


def test_the_point_and_the_views_come_back_as_they_were_kept(tmp_path, capsys):
    _measured(tmp_path)
    again = _progress(tmp_path)
    assert again.point["orp"]["views"] == 40 and isinstance(again.point["orp"]["views"], int)  # NumPy scalars made plain
    assert again.point["orp"]["points"] == [[0.3, 0.5, 0.3, 0.9]] and again.point["notes"] == ["a note"]
    assert sorted(again.views) == [0, 4] and again.views[0]["rows"] == _rows(0)
    assert again.views[4]["sweep_rows"][0]["value"] == 0.2 and again.views[4]["load"] is None
    grid = again.grid(0)
    assert set(grid) == {"truth", "imls_im"} and grid["truth"].dtype == np.uint8 and grid["imls_im"].dtype == bool
    assert again.sitting == 2 and "resuming: 2 of the 3 views already measured" in capsys.readouterr().err
    assert again.note().startswith("Resumed evaluation (sitting 2): 2 of the 3 views were measured in an earlier sitting")
    assert _progress(tmp_path / "fresh").note() is None  # one sitting: nothing to say


def test_a_point_alone_is_restored_and_a_later_save_keeps_its_sitting(tmp_path):
    pr = _progress(tmp_path)
    pr.save_point(POINT)
    again = _progress(tmp_path)
    assert again.views == {} and again.point["imls_mean"] == 0.3 and again.sitting == 2
    again.save_point({**again.point, "two_pass": {"share": 0.5}})
    third = _progress(tmp_path)
    assert third.point["two_pass"] == {"share": 0.5} and third.point["sitting"] == 1


def test_an_interrupted_line_is_dropped_and_the_file_repaired_in_one_line(tmp_path, capsys):
    _measured(tmp_path)
    path = tmp_path / "partial" / "views.jsonl"
    with open(path, "a") as f:
        f.write('{"view": 8, "rows": [{"vi')  # killed mid-write
    capsys.readouterr()
    again = _progress(tmp_path)
    err = [ln for ln in capsys.readouterr().err.splitlines() if "dropped" in ln]
    assert sorted(again.views) == [0, 4] and len(err) == 1 and "line 3: an unreadable line (an interrupted write)" in err[0]
    assert len(path.read_text().splitlines()) == 2  # repaired: the next resume reads it cleanly
    _progress(tmp_path)
    assert "dropped" not in capsys.readouterr().err


@pytest.mark.parametrize("spoil, why", [
    (lambda rec: rec.update(view=99), "view 99 is not evaluated"),
    (lambda rec: rec["rows"][1].update(view=0), "view 4's rows are malformed"),
    (lambda rec: rec.update(rows=[]), "view 4's rows are malformed"),
    (lambda rec: rec.update(sweep_rows=None), "view 4's sweep rows are malformed"),
])
def test_a_record_that_does_not_hold_is_measured_again(tmp_path, capsys, spoil, why):
    _measured(tmp_path)
    path = tmp_path / "partial" / "views.jsonl"
    lines = [json.loads(x) for x in path.read_text().splitlines()]
    spoil(lines[1])
    path.write_text("".join(json.dumps(x) + "\n" for x in lines))
    again = _progress(tmp_path)
    assert sorted(again.views) == [0] and why in capsys.readouterr().err


def test_a_view_whose_grid_images_are_gone_is_measured_again(tmp_path, capsys):
    _measured(tmp_path)
    (tmp_path / "partial" / "grid-0.npz").unlink()
    assert sorted(_progress(tmp_path).views) == [4] and "view 0's grid images are missing" in capsys.readouterr().err


@pytest.mark.parametrize("spoil, why", [
    (lambda path: path.write_text("{not json"), "point.json is unreadable (JSONDecodeError)"),
    (lambda path: path.write_text(json.dumps({**json.loads(path.read_text()), "format": FORMAT + 1})),
     f"point.json is not a format-{FORMAT} record"),
    (lambda path: path.write_text(json.dumps({**json.loads(path.read_text()), "positions": [0, 4]})),
     "point.json was measured on other views"),
    (lambda path: path.write_text(json.dumps({k: v for k, v in json.loads(path.read_text()).items() if k != "lift"})),
     "point.json lacks some of orp, imls_mean, lift, notes"),
    (lambda path: path.unlink(), None),  # views without their point: dropped silently (never trusted)
])
def test_a_point_that_does_not_hold_starts_the_evaluation_over(tmp_path, capsys, spoil, why):
    _measured(tmp_path)
    spoil(tmp_path / "partial" / "point.json")
    capsys.readouterr()
    again = _progress(tmp_path)
    err = capsys.readouterr().err.strip().splitlines()
    assert again.point == {} and again.views == {} and again.sitting == 1 and not (tmp_path / "partial").exists()
    if why is not None:
        assert len(err) == 1 and why in err[0] and err[0].endswith("this evaluation starts over")


def test_resume_false_discards_the_record(tmp_path, capsys):
    _measured(tmp_path)
    again = _progress(tmp_path, resume=False)
    assert again.point == {} and again.views == {} and "resume=false: the partial results" in capsys.readouterr().err


def test_views_need_their_point_and_finish_removes_the_record(tmp_path):
    pr = _progress(tmp_path)
    with pytest.raises(RuntimeError, match="add_view before save_point"):
        pr.add_view(0, _rows(0), [], None, None)
    pr = _measured(tmp_path)
    pr.finish()
    assert not (tmp_path / "partial").exists()


def test_plain_makes_numpy_values_json_and_refuses_the_rest():
    assert json.dumps({"a": np.float32(0.5), "b": np.arange(2), "c": np.bool_(False)}, default=plain) == \
        '{"a": 0.5, "b": [0, 1], "c": false}'
    with pytest.raises(TypeError, match="object is not JSON serializable"):
        plain(object())
