"""Loading task checkpoints and the cross-checks between them (``imls_lightning.inference.checkpoints``).

The hyperparameter checks run on plain dicts; loading runs on the session's real tiny checkpoints
(``tiny_checkpoints`` in conftest.py).
"""
from __future__ import annotations

from pathlib import Path

import pytest
import torch

from imls_lightning.base.errors import InputError
from imls_lightning.inference.checkpoints import (
    check_resolution,
    check_same_pattern,
    check_trained_on,
    config_diff,
    load_ims_and_recnn,
    load_ims_nets,
    load_nets,
    load_product,
    load_task,
    require_pim_target,
    require_recnn,
    same_pattern,
    task_class,
    task_path,
)
from imls_lightning.core.patterns import build_pattern

DOWN2 = {"kind": "downsample", "factor": 2}
DOWN4 = {"kind": "downsample", "factor": 4}
P32 = build_pattern(DOWN2, 32)


def sealed(record: dict, ckpt) -> str:
    """``record`` as JSON with the digest the evaluation would give it for ``ckpt`` (a test's edit, re-sealed, so that
    the check behind the digest is the one tested)."""
    import json

    from imls_lightning.base.config import file_hash
    from imls_lightning.inference.operating_point import record_digest

    return json.dumps({**record, "digest": record_digest(record, file_hash(ckpt, length=64))})


def hp(pattern=DOWN2, fr_size=32, **kw):
    return {"pattern": pattern, "fr_size": fr_size, **kw}


def one_line(err) -> str:
    msg = str(err.value)
    assert "\n" not in msg
    return msg


# ---- pattern and resolution --------------------------------------------------------------------
def test_same_pattern():
    assert same_pattern(hp(), P32)
    assert not same_pattern(hp(DOWN4), P32)          # other pixels
    assert not same_pattern(hp(fr_size=64), P32)      # same kind, other resolution
    assert not same_pattern({"fr_size": 32}, P32)      # no pattern recorded
    assert not same_pattern(hp({"kind": "nope"}), P32)  # a pattern this version cannot build


def test_check_same_pattern_passes_and_raises():
    check_same_pattern(hp(), P32, key="recnn.checkpoint")
    with pytest.raises(InputError) as err:
        check_same_pattern(hp(DOWN4), P32, key="recnn.checkpoint", path="/r.ckpt", network="RecNN", against="the IML",
                           hint="use another")
    msg = one_line(err)
    assert msg.startswith("recnn.checkpoint=/r.ckpt: the RecNN was trained on another sampling pattern or resolution (downsample 32->8")
    assert "the IML: downsample 32->16" in msg and msg.endswith("; use another")
    # without a path (a constructor only has hyperparameters); an unbuildable pattern is shown as given
    with pytest.raises(InputError, match=r"^iml.checkpoint: the IML was trained on another .*pattern=\{'kind': 'nope'\} at 32\^2"):
        check_same_pattern(hp({"kind": "nope"}), P32, key="iml.checkpoint", network="IML")


def test_check_resolution():
    check_resolution(hp(), 32, key="checkpoints.las")
    with pytest.raises(InputError) as err:
        check_resolution(hp(fr_size=64), 32, key="checkpoints.ims", path="/i.ckpt", network="IMS", against="this evaluation uses")
    assert one_line(err) == ("checkpoints.ims=/i.ckpt: the IMS was trained at data.resolution=64, this evaluation uses 32; "
                             "pass data.resolution=64 (and the data group it was trained with)")
    with pytest.raises(InputError, match=r"the cache c holds 32; use data.resolution=64$"):
        check_resolution(hp(fr_size=64), 32, key="iml.checkpoint", against="the cache c holds", hint="use data.resolution=64")


# ---- what an IMS checkpoint carries ------------------------------------------------------------
def test_require_recnn():
    net = torch.nn.Identity()
    assert require_recnn(net, key="ims_checkpoint") is net
    with pytest.raises(InputError) as err:
        require_recnn(None, key="checkpoints.ims", path="/i.ckpt", recnn_key="checkpoints.recnn")
    assert one_line(err) == ("checkpoints.ims=/i.ckpt: carries no RecNN (its IML was trained standalone); "
                             "pass checkpoints.recnn=<RecNN .ckpt>")


def test_require_pim_target():
    require_pim_target({"target": "pim"})
    for target in ("im", None):
        with pytest.raises(InputError, match=rf"^ims_checkpoint=/i.ckpt: its IMS was trained with model.target={target}; "
                                             r"rescaling needs an IMS trained with model.target=pim$"):
            require_pim_target({"target": target}, path="/i.ckpt", what="rescaling")


# ---- scene and renderer ------------------------------------------------------------------------
def test_config_diff():
    assert config_diff({"a": 1, "b": [1, 2]}, {"a": 1, "b": [1, 2]}) == []
    assert config_diff({"a": 1, "b": {"c": 2}}, {"a": 2, "b": {"c": 3}, "d": 0}) == ["a", "b.c", "d"]
    assert config_diff({"p": [1, 2]}, {"p": [1, 3]}) == ["p"]
    assert config_diff({"volume_path": "/x/../x/v.raw"}, {"volume_path": "/x/v.raw"}) == []  # the same file


def test_check_trained_on():
    scene = {"name": "tiny", "transfer_function": {"colormap": "gray"}}
    renderer = {"name": "numba", "step": 0.5}
    trained = {"scene": scene, "renderer": renderer}
    check_trained_on(trained, scene, renderer, key="ims_checkpoint")
    check_trained_on({}, {"name": "other"}, {"name": "vtk"}, key="ims_checkpoint")  # nothing recorded: nothing to check
    other = {"name": "tiny", "transfer_function": {"colormap": "viridis"}}
    with pytest.raises(InputError) as err:
        check_trained_on(trained, other, renderer, key="checkpoints.ims", path="/i.ckpt", against="this evaluation",
                         escape="or allow_mismatch=true")
    assert one_line(err) == ("checkpoints.ims=/i.ckpt: trained on scene=tiny, this evaluation uses scene=tiny (scene differs in "
                             "transfer_function.colormap); pass scene=tiny (with the overrides it was trained with), or allow_mismatch=true")
    with pytest.raises(InputError, match=r"^ims_checkpoint: trained with renderer=numba, this run uses renderer=vtk .*pass renderer=numba$"):
        check_trained_on(trained, scene, {"name": "vtk"}, key="ims_checkpoint")


# ---- loading -----------------------------------------------------------------------------------
def test_task_class():
    assert task_class("RecNNTask").__name__ == "RecNNTask"
    with pytest.raises(InputError, match=r"^checkpoint names task 'os.system': expected one of \['IMLTask'"):
        task_class("os.system")


def test_load_task(tiny_checkpoints):
    task = load_task(tiny_checkpoints["recnn"], expect="RecNNTask", what="recnn.checkpoint")
    assert type(task).__name__ == "RecNNTask" and not task.training
    assert task_path(task) == str(tiny_checkpoints["recnn"]) and task_path(torch.nn.Identity()) is None
    assert type(load_task(tiny_checkpoints["ims"])).__name__ == "IMSTask"  # no expectation: any task


def test_exception_load_task(tiny_checkpoints, tmp_path):
    ck = tiny_checkpoints["recnn"]
    with pytest.raises(InputError) as err:
        load_task(ck, expect="IMSTask", what="checkpoints.ims")
    assert one_line(err) == f"checkpoints.ims={ck}: is a RecNNTask checkpoint, expected a IMSTask checkpoint"
    with pytest.raises(InputError, match=r"^x=/nonexistent/a.ckpt: file not found"):
        load_task("/nonexistent/a.ckpt", what="x")
    raw = torch.load(ck, map_location="cpu", weights_only=True)
    nameless = {k: v for k, v in raw.items() if k != "imls_task"}
    torch.save(nameless, tmp_path / "nameless.ckpt")
    with pytest.raises(InputError, match=r"nameless.ckpt: not a checkpoint of this project \(no task name\)$"):
        load_task(tmp_path / "nameless.ckpt")
    raw["imls_task"] = "NopeTask"
    torch.save(raw, tmp_path / "foreign.ckpt")
    with pytest.raises(InputError, match="checkpoint names task 'NopeTask'"):
        load_task(tmp_path / "foreign.ckpt")
    raw["imls_task"] = "RecNNTask"
    raw["state_dict"] = {f"{k}_renamed": v for k, v in raw["state_dict"].items()}
    torch.save(raw, tmp_path / "misfit.ckpt")
    with pytest.raises(InputError, match=r"misfit.ckpt: weights do not fit the network it describes \(missing"):
        load_task(tmp_path / "misfit.ckpt")


def test_a_task_loads_its_own_class_without_the_registry(tiny_checkpoints):
    """Tasks load the tasks they build on by class (``from_checkpoint``): no task imports this module,
    which loads the tasks by name (``tests/test_architecture.py``)."""
    from imls_lightning.inference import checkpoints
    from imls_lightning.tasks import checkpoint_checks
    from imls_lightning.tasks.iml import IMLTask
    from imls_lightning.tasks.recnn import RecNNTask

    ck = tiny_checkpoints["recnn"]
    task = RecNNTask.from_checkpoint(ck, what="recnn.checkpoint")
    assert type(task) is RecNNTask and not task.training and task_path(task) == str(ck)
    for a, b in zip(task.state_dict().values(), load_task(ck).state_dict().values()):
        assert torch.equal(a, b)
    with pytest.raises(InputError) as err:
        IMLTask.from_checkpoint(ck, what="iml.checkpoint")
    assert one_line(err) == f"iml.checkpoint={ck}: is a RecNNTask checkpoint, expected a IMLTask checkpoint"
    assert checkpoints.check_same_pattern is checkpoint_checks.check_same_pattern  # one home, re-exported


def test_load_ims_and_recnn(tiny_checkpoints):
    task, recnn = load_ims_and_recnn(str(tiny_checkpoints["ims"]))
    assert type(task).__name__ == "IMSTask" and recnn is None
    task, recnn = load_ims_and_recnn(str(tiny_checkpoints["ims"]), str(tiny_checkpoints["recnn"]))
    rt = load_task(tiny_checkpoints["recnn"])
    for a, b in zip(recnn.state_dict().values(), rt.net.state_dict().values()):
        assert torch.equal(a, b)


def test_exception_load_ims_and_recnn(tiny_checkpoints, tmp_path):
    # the same RecNN, recorded as trained at twice the resolution (its weights still fit)
    raw = torch.load(tiny_checkpoints["recnn"], map_location="cpu", weights_only=True)
    raw["hyper_parameters"]["fr_size"] = 2 * int(raw["hyper_parameters"]["fr_size"])
    other = tmp_path / "recnn64.ckpt"
    torch.save(raw, other)
    with pytest.raises(InputError) as err:
        load_ims_and_recnn(str(tiny_checkpoints["ims"]), str(other))
    assert one_line(err).startswith(f"recnn_checkpoint={other}: the RecNN was trained on another sampling pattern or resolution")
    with pytest.raises(InputError, match=r"^checkpoints.recnn=.*expected a RecNNTask checkpoint"):
        load_ims_and_recnn(str(tiny_checkpoints["ims"]), str(tiny_checkpoints["iml"]), keys=("checkpoints.ims", "checkpoints.recnn"))
    with pytest.raises(InputError, match=r"^ims_checkpoint=.*is a IMLTask checkpoint, expected a IMSTask"):
        load_ims_and_recnn(str(tiny_checkpoints["iml"]))


def test_load_ims_nets_builds_the_product_without_the_task(tiny_checkpoints, monkeypatch):
    """Inference builds the bare networks the IMS checkpoint needs (generator, IML decoder, RecNN) and
    loads their weights; no task, discriminator or IML encoder is constructed, and the nets compute
    what the whole task computes."""
    from imls_lightning.models.ims import IMSMaskHead
    from imls_lightning.tasks.ims import IMSTask
    from imls_lightning.tasks.recnn import RecNNTask

    ck = str(tiny_checkpoints["ims_pim"])
    task = load_task(ck, expect="IMSTask")

    def no_task(*args, **kwargs):
        raise AssertionError("a task was built")

    monkeypatch.setattr(IMSTask, "__init__", no_task)
    monkeypatch.setattr(RecNNTask, "__init__", no_task)
    nets = load_ims_nets(ck, str(tiny_checkpoints["recnn"]))  # the RecNN checkpoint replaces the stored one
    monkeypatch.undo()
    assert isinstance(nets.head, IMSMaskHead) and nets.target == "pim" and nets.trained_mean == float(task.iml.mean)
    names = {type(m).__name__ for net in (nets.head, nets.decoder, nets.recnn) for m in net.modules()}
    assert "IMSDiscriminator" not in names and "IMLNet" not in names and nets.pattern.fingerprint() == task.pattern.fingerprint()
    # the IML's RecNN was frozen: the replacement has the stored weights (load_ims_and_recnn compares it with the task's)
    assert all(torch.equal(a, b) for a, b in zip(nets.recnn.state_dict().values(), task.recnn.state_dict().values()))
    views = torch.tensor([[0.0, 0.0, 3.2, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0], [2.5, 1.0, 1.5, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0]])
    with torch.inference_mode():
        for mean, lift in ((None, False), (0.05, False), (0.9, False), (0.9, True)):
            assert torch.equal(nets.head(views, mean, lift), task.predict_im(views, mean, lift)), (mean, lift)
        im = task.predict_im(views).float()
        c = torch.rand(2, 3, nets.pattern.c_size, nets.pattern.c_size, generator=torch.Generator().manual_seed(0))
        assert torch.equal(nets.recnn(nets.decoder(im * c, im)), task.recnn(task.decoder(im * c, im)))


def test_load_product_reads_the_operating_point_and_refuses_wrong_files(tiny_checkpoints, tmp_path, capsys):
    from imls_lightning.inference.operating_point import ORPRecord, write_operating_point
    import shutil

    ck = tmp_path / "ims.ckpt"
    shutil.copy(tiny_checkpoints["ims_pim"], ck)
    plain = load_product(str(ck))
    assert plain.mean is None and plain.lift is False and plain.record is None
    write_operating_point(ck, ORPRecord(mean=0.6, lift=True, c_share=0.6, ipr=0.1, epsilon_db=1.0))
    rec = load_product(str(ck))
    assert rec.mean == 0.6 and rec.lift is True and rec.record.mean == 0.6
    over = load_product(str(ck), share=0.3)
    assert over.mean == 0.3 and over.lift is False and over.record is None
    with pytest.raises(InputError, match=r"^ims_checkpoint=.*is a IMLTask checkpoint, expected a IMSTask"):
        load_ims_nets(str(tiny_checkpoints["iml"]))
    with pytest.raises(InputError, match=r"^recnn_checkpoint=.*is a IMLTask checkpoint, expected a RecNNTask"):
        load_ims_nets(str(ck), str(tiny_checkpoints["iml"]))
    raw = torch.load(tiny_checkpoints["recnn"], map_location="cpu", weights_only=True)
    raw["state_dict"] = {k: v for k, v in raw["state_dict"].items() if not k.endswith(".bias")}
    torch.save(raw, tmp_path / "cut.ckpt")
    with pytest.raises(InputError, match=r"weights do not fit the network it describes \(net: missing"):
        load_nets(tmp_path / "cut.ckpt", expect="RecNNTask", what="recnn_checkpoint")


def test_a_point_by_camera_distance_travels_with_the_checkpoint(tiny_checkpoints, tmp_path, capsys):
    """An evaluation with orp_by_distance records its bands; the product loaded from the checkpoint alone runs
    them (each view at its band's mean value), an explicit mean value overrides them, a malformed band record is
    ignored with a one-line warning."""
    import json
    import shutil

    from imls_lightning.inference.operating_point import ORPRecord, read_operating_point, sidecar_path, write_operating_point
    from imls_lightning.inference.pipeline import IMLSRenderer, NetOptions

    ck = tmp_path / "ims.ckpt"
    shutil.copy(tiny_checkpoints["ims_pim"], ck)
    bands = {"edges": [3.5, 4.0], "means": [0.95, 0.6, 0.3], "c_shares": [0.9, 0.6, 0.3], "gaps_db": [0.8, 0.5, 0.2],
             "views": [2, 2, 2]}
    point = ORPRecord(mean=0.95, lift=True, c_share=0.9, ipr=0.2, epsilon_db=1.0, by_distance=bands)
    write_operating_point(ck, point)
    read = read_operating_point(ck, log=None)
    assert read.by_distance == bands and "by camera distance, near to far: u = 0.950 / 0.600 / 0.300 (90 / 60 / 30 % of C) " \
                                         "split at 3.50, 4.00" in read.describe()
    product = load_product(str(ck))
    assert product.mean == 0.95 and product.point.bands.shares == pytest.approx((0.95, 0.6, 0.3))
    r = IMLSRenderer.from_checkpoints(str(ck), opts=NetOptions(device="cpu"))
    near, far = [0.0, 0.0, 3.2, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 4.4, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0]
    got = {u: r.run(v).info for u, v in ((0.95, near), (0.3, far))}
    assert {u: info["mean"] for u, info in got.items()} == pytest.approx({0.95: 0.95, 0.3: 0.3})
    fixed = IMLSRenderer.from_checkpoints(str(ck), opts=NetOptions(device="cpu"), mean=0.3)
    assert fixed.by_distance is None and "mean" not in fixed.run(far).info
    capsys.readouterr()
    rec = json.loads(sidecar_path(ck).read_text())
    sidecar_path(ck).write_text(sealed({**rec, "by_distance": {**bands, "edges": [4.0, 3.5]}}, ck))
    assert load_product(str(ck)).point is None
    err = [ln for ln in capsys.readouterr().err.splitlines() if ln.startswith("[orp]")]
    assert len(err) == 1 and "ignored: malformed (InputError: by_distance: band edges [4.0, 3.5]" in err[0]


def test_a_sharpened_point_travels_with_the_checkpoint(tiny_checkpoints, tmp_path, capsys):
    """A point searched at an IMS mask sharpness records it; renderers and exports built from the checkpoint alone
    sharpen their masks the same way; a record from before the key reads as 1 (the paper's masks); a sharpness out of
    range is a malformed record, ignored with one line."""
    import json
    import shutil

    from imls_lightning.inference.operating_point import ORPRecord, read_operating_point, sidecar_path, write_operating_point
    from imls_lightning.inference.pipeline import IMLSRenderer, NetOptions

    ck = tmp_path / "ims.ckpt"
    shutil.copy(tiny_checkpoints["ims_pim"], ck)
    write_operating_point(ck, ORPRecord(mean=0.4, lift=True, c_share=0.4, ipr=0.1, epsilon_db=1.0, sharpness=2.0))
    assert read_operating_point(ck, log=None).sharpness == 2.0
    r = IMLSRenderer.from_checkpoints(str(ck), opts=NetOptions(device="cpu"))
    assert r.point.sharpness == 2.0 and r.mean == 0.4 and r.lift
    view = torch.tensor([[0.0, 0.0, 3.2, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0]])
    plain = load_ims_nets(str(ck)).head
    assert torch.equal(r.predict_im(view), plain.with_sharpness(2.0)(view, 0.4, True))
    rec = json.loads(sidecar_path(ck).read_text())
    sidecar_path(ck).write_text(sealed({k: v for k, v in rec.items() if k != "sharpness"}, ck))
    assert read_operating_point(ck, log=None).sharpness == 1.0 and load_product(str(ck)).point.sharpness == 1.0
    capsys.readouterr()
    sidecar_path(ck).write_text(sealed({**rec, "sharpness": 0.5}, ck))
    assert load_product(str(ck)).record is None
    err = [ln for ln in capsys.readouterr().err.splitlines() if ln.startswith("[orp]")]
    assert len(err) == 1 and "ignored: malformed (InputError: sharpness=0.5: expected a number in [1, 8]" in err[0]


def test_a_floored_point_travels_with_the_checkpoint(tiny_checkpoints, tmp_path, capsys):
    """A point with an object floor records it; renderers built from the checkpoint alone raise each view's u the
    same way and describe it; a record from before the key reads as no floor; a bad margin is a malformed record,
    ignored with one line."""
    import json
    import shutil

    from imls_lightning.inference.operating_point import ORPRecord, read_operating_point, sidecar_path, write_operating_point
    from imls_lightning.inference.pipeline import IMLSRenderer, NetOptions

    ck = tmp_path / "ims.ckpt"
    shutil.copy(tiny_checkpoints["ims_pim"], ck)
    floor = {"margin": 0.12, "tau": 0.2, "c_share": 0.43, "gap_db": 0.1, "gap_bound_db": 0.6, "views": 40}
    write_operating_point(ck, ORPRecord(mean=0.3, lift=True, c_share=0.3, ipr=0.1, epsilon_db=1.0, object_floor=floor))
    point = read_operating_point(ck, log=None)
    assert point.object_floor == floor and point.floor == (0.12, 0.2)
    assert "each view at least its object (PIM' > 0.2) + 0.12 of C" in point.describe()
    r = IMLSRenderer.from_checkpoints(str(ck), opts=NetOptions(device="cpu"))
    assert r.point.object_floor == (0.12, 0.2) and r.mean == 0.3 and r.lift
    view = torch.tensor([[0.0, 0.0, 3.2, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0]])
    plain = load_ims_nets(str(ck)).head
    assert plain.object_floor is None
    assert torch.equal(r.predict_im(view), plain.with_object_floor(0.12, 0.2)(view, 0.3, True))
    assert load_product(str(ck), share=0.5).point.object_floor is None  # an explicit mean: nothing is read
    rec = json.loads(sidecar_path(ck).read_text())
    sidecar_path(ck).write_text(sealed({k: v for k, v in rec.items() if k != "object_floor"}, ck))
    assert read_operating_point(ck, log=None).object_floor is None and load_product(str(ck)).point.object_floor is None
    capsys.readouterr()
    sidecar_path(ck).write_text(sealed({**rec, "object_floor": {"margin": 1.5, "tau": 0.2}}, ck))
    assert load_product(str(ck)).record is None
    err = [ln for ln in capsys.readouterr().err.splitlines() if ln.startswith("[orp]")]
    assert len(err) == 1 and "ignored: malformed (InputError: object_floor.margin=1.5: expected a share of the C-Image" in err[0]


def test_a_point_floored_per_band_travels_with_the_checkpoint(tiny_checkpoints, tmp_path, capsys):
    """A by-distance point whose object floor has a margin per band (orp_object_floor_by_band) records them; a renderer
    built from the checkpoint alone runs each view at its band's mean value and margin (the one-margin head's masks at
    that margin; None: the unfloored head's) and describes them; band margins without bands, or not one per band, are a
    malformed record, ignored with one line."""
    import json
    import shutil

    from imls_lightning.inference.operating_point import ORPRecord, read_operating_point, sidecar_path, write_operating_point
    from imls_lightning.inference.pipeline import IMLSRenderer, NetOptions

    ck = tmp_path / "ims.ckpt"
    shutil.copy(tiny_checkpoints["ims_pim"], ck)
    bands = {"edges": [3.0], "means": [0.5, 0.2]}
    floor = {"margin": 0.3, "tau": 0.2, "band_margins": [0.3, None], "c_share": 0.4, "gap_db": 0.1, "gap_bound_db": 0.6,
             "views": 40}
    write_operating_point(ck, ORPRecord(mean=0.5, lift=True, c_share=0.4, ipr=0.1, epsilon_db=1.0, by_distance=bands,
                                             object_floor=floor))
    point = read_operating_point(ck, log=None)
    assert point.object_floor == floor and point.point.bands.floor_margins == (0.3, None)
    assert "+ (near to far) 0.3 / none of C" in point.describe()
    r = IMLSRenderer.from_checkpoints(str(ck), opts=NetOptions(device="cpu"))
    plain = load_ims_nets(str(ck)).head
    near = torch.tensor([[0.0, 0.0, 2.5, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0]])
    far = torch.tensor([[0.0, 0.0, 3.5, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0]])
    assert torch.equal(r.predict_im(near), plain.with_object_floor(0.3, 0.2)(near, 0.5, True))
    assert torch.equal(r.predict_im(far), plain(far, 0.2, True))
    rec = json.loads(sidecar_path(ck).read_text())
    for bad, msg in (({**rec, "by_distance": None}, "object_floor.band_margins without by_distance bands"),
                     ({**rec, "object_floor": {**floor, "band_margins": [0.3]}}, "floor_margins=[0.3]: expected 2 margins")):
        capsys.readouterr()
        sidecar_path(ck).write_text(sealed(bad, ck))
        assert load_product(str(ck)).record is None
        err = [ln for ln in capsys.readouterr().err.splitlines() if ln.startswith("[orp]")]
        assert len(err) == 1 and "ignored: malformed" in err[0] and msg in err[0], err


# ---- checkpoints written before a module moved --------------------------------------------------
ROW = Path(__file__).resolve().parents[2] / "benchmarks" / "rows" / "seed_whole"


@pytest.mark.parametrize("name, task", [("recnn.ckpt", "RecNNTask"), ("recnn_sparser.ckpt", "RecNNTask"),
                                        ("iml.ckpt", "IMLTask"), ("blue_noise.ckpt", "IMLTask"),
                                        ("ims.ckpt", "IMSTask"), ("las.ckpt", "LASTask")])
def test_committed_row_checkpoints_still_load(name, task):
    """The row's committed checkpoints were saved before the ray casters, the fill and the checks changed rooms
    (issue 87): a checkpoint names its task by class name and its RecNN by ``_target_``, never a moved module, so
    each loads as the task it names, and the IMS checkpoint gives the product's bare networks."""
    assert type(load_task(ROW / name, expect=task)).__name__ == task
    if name == "ims.ckpt":
        nets = load_ims_nets(ROW / name)
        assert nets.head is not None and nets.decoder is not None and nets.recnn is not None
