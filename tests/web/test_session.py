"""imls_lightning.web.session: the browser viewer's state, on real tiny checkpoints (no browser)."""
from __future__ import annotations

import numpy as np
import pytest

from imls_lightning.base.errors import InputError
from imls_lightning.inference.pipeline import NetOptions
from imls_lightning.web.session import ViewerSession, png_data_url


@pytest.fixture(scope="module")
def predictor_file(tmp_path_factory):
    """A real (untrained) per-view mean predictor file, as python -m imls_lightning.adaptive saves it."""
    from imls_lightning.adaptive.predictor import MeanPredictor

    return MeanPredictor(hidden=8, layers=1).save(tmp_path_factory.mktemp("predictor") / "mean_predictor.pt")


@pytest.fixture(scope="module")
def session(tiny_checkpoints, predictor_file):
    return ViewerSession.from_checkpoints(str(tiny_checkpoints["ims_pim"]), las_checkpoint=str(tiny_checkpoints["las"]),
                                          predictor=str(predictor_file), opts=NetOptions(device="cpu"))


def test_smoke_every_method_renders_a_scored_frame(session):
    m = session.pattern.fr_size
    iprs = {}
    for name in session.methods:
        session.set_method(name)
        f = session.frame()
        assert f.image.shape == (m, m, 3) and f.image.dtype == np.uint8 and f.mask.shape == (m, m)
        assert f.error.shape == (m, m, 3) and np.isfinite(f.psnr) and f.stages_ms["total"] > 0
        iprs[name] = f.ipr
    assert set(iprs) == {"imls", "adaptive", "recnn", "las", "truth"}
    assert iprs["truth"] == 1.0 and iprs["recnn"] == pytest.approx(session.pattern.sampling_ratio)
    assert session.las_method.ipr == 1.0  # LAS runs at IML/S's IPR as an argument: the method is not changed
    session.set_method("truth")
    assert session.frame().psnr >= 99.9  # the ground truth scored against itself
    assert len(session.history) >= 5


def test_adaptive_method_reports_the_views_mean(session):
    session.set_method("adaptive")
    f = session.frame()
    assert 0.01 <= f.share <= 1.0 and "mean" in f.stages_ms and f.mask.any()


def test_share_slider_changes_the_share_ray_cast(session):
    session.set_method("imls")
    session.set_share(0.05)
    low = session.frame()
    session.set_share(1.0)
    high = session.frame()
    assert low.share == 0.05 and high.share == 1.0 and high.ipr > low.ipr
    # set_mean, its older name, still works (the paper's mean value u is the share), with a DeprecationWarning
    with pytest.warns(DeprecationWarning, match="set_share"):
        session.set_mean(0.3)
    assert session.share == session.mean == 0.3


def test_orbit_zoom_reset_move_the_camera_and_the_image(session):
    session.set_method("truth")
    first = session.frame().image
    session.orbit(60, 10)
    session.zoom(3)
    assert session.azimuth != session.home[0] and session.distance < session.home[2]
    assert not np.array_equal(session.frame().image, first)
    session.reset()
    assert (session.azimuth, session.elevation, session.distance) == session.home


def test_png_data_url_round_trip():
    import base64
    import io

    from PIL import Image

    img = np.arange(48, dtype=np.uint8).reshape(4, 4, 3)
    url = png_data_url(img)
    assert url.startswith("data:image/png;base64,")
    back = np.asarray(Image.open(io.BytesIO(base64.b64decode(url.split(",", 1)[1]))))
    assert np.array_equal(back, img)
    assert png_data_url(np.eye(3, dtype=bool)).startswith("data:image/png")


def test_exception_bad_inputs_are_one_line(session, tiny_checkpoints, tmp_path):
    with pytest.raises(InputError, match=r"^method='x': expected one of imls, adaptive, recnn, las, truth$"):
        session.set_method("x")
    with pytest.raises(InputError, match=r"^share=2.0: expected a number in \[0.01, 1\]$"):
        session.set_share(2.0)
    with pytest.raises(InputError, match="^ims_checkpoint="):
        ViewerSession.from_checkpoints(str(tmp_path / "missing.ckpt"))
    with pytest.raises(InputError, match="^ims_checkpoint=.*RecNNTask"):
        ViewerSession.from_checkpoints(str(tiny_checkpoints["recnn"]))
    with pytest.raises(InputError, match="^predictor="):
        ViewerSession.from_checkpoints(str(tiny_checkpoints["ims_pim"]), predictor=str(tiny_checkpoints["recnn"]))
    binary = ViewerSession.from_checkpoints(str(tiny_checkpoints["ims"]), opts=NetOptions(device="cpu"))
    assert "adaptive" not in binary.methods and "las" not in binary.methods
    with pytest.raises(InputError, match="model.target=im"):
        binary.set_share(0.5)  # a binary-mask IMS cannot be rescaled


def test_the_session_opens_at_the_recorded_operating_point(tiny_checkpoints, tmp_path, capsys):
    """The browser viewer opens where the evaluation's record (beside the IMS checkpoint) says, its
    masks lifted if the evaluation lifted them; share= (mean=: its older name) overrides it; without a record, the
    trained share."""
    import shutil

    from imls_lightning.inference.operating_point import ORPRecord, write_operating_point

    ckpt, cpu = tmp_path / "ims.ckpt", NetOptions(device="cpu")
    shutil.copy(tiny_checkpoints["ims_pim"], ckpt)
    plain = ViewerSession.from_checkpoints(str(ckpt), opts=cpu)
    assert plain.share == plain.trained_mean and plain.operating_point is None
    assert "no recorded operating point" in capsys.readouterr().err
    point = ORPRecord(mean=0.4567, lift=True, c_share=0.45, ipr=0.11, epsilon_db=1.0)
    write_operating_point(ckpt, point)
    s = ViewerSession.from_checkpoints(str(ckpt), opts=cpu)
    assert s.share == 0.4567 and s.operating_point == point and s.lift is True
    f = s.frame()
    assert f.share == 0.4567 and s._imls_at(0.4567).mean == 0.4567
    over = ViewerSession.from_checkpoints(str(ckpt), opts=cpu, share=0.3)
    assert over.share == 0.3 and over.operating_point is None and over.lift is False
    assert ViewerSession.from_checkpoints(str(ckpt), opts=cpu, mean=0.3).share == 0.3


def test_the_session_runs_a_point_recorded_by_camera_distance(tiny_checkpoints, tmp_path, capsys):
    """A record with bands of camera distance: the session opens at it and IML/S runs each view at its band's share
    (the frame says it is the view's); a share set with the slider holds for every view."""
    import shutil

    from imls_lightning.inference.operating_point import ORPRecord, write_operating_point
    from imls_lightning.web.app import stats_text

    ckpt = tmp_path / "ims.ckpt"
    shutil.copy(tiny_checkpoints["ims_pim"], ckpt)
    bands = {"edges": [3.6], "means": [0.9, 0.35]}
    write_operating_point(ckpt, ORPRecord(mean=0.9, lift=True, c_share=0.8, ipr=0.2, epsilon_db=1.0, by_distance=bands))
    s = ViewerSession.from_checkpoints(str(ckpt), opts=NetOptions(device="cpu"), distance=4.2)
    assert s.share == 0.9 and s.by_distance is not None
    far = s.frame()
    assert far.view_share and far.share == pytest.approx(0.35) and "(this view's)" in stats_text(far)
    s.distance = 3.1
    assert s.frame().share == pytest.approx(0.9)
    s.set_share(0.5)
    fixed = s.frame()
    assert not fixed.view_share and fixed.share == 0.5 and "(this view's)" not in stats_text(fixed)
