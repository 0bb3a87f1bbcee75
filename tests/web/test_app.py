"""imls_lightning.web.app and the CLI: the page served on localhost, driven by headless Chromium.

The browser test finds Debian's ``chromium`` and ``chromedriver`` (``make test-browser`` installs
them) and skips, saying why, when either or selenium is missing. Screenshots go to
``$IMLS_TEST_ARTIFACTS`` (default ``test-artifacts/`` in the repository).
"""
from __future__ import annotations

import os
import re
import shutil
import socket
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import pytest

from imls_lightning.web.app import latency_psnr_svg, stats_text
from imls_lightning.web.session import Frame

ROOT = Path(__file__).resolve().parents[2]
ARTIFACTS = Path(os.environ.get("IMLS_TEST_ARTIFACTS", ROOT / "test-artifacts"))


def test_latency_psnr_svg_marks_the_current_point():
    svg = latency_psnr_svg([("imls", 10.0, 30.0), ("recnn", 20.0, float("nan")), ("las", 30.0, 25.0)], (10.0, 30.0))
    assert svg.startswith("<svg") and 'data-points="2"' in svg and svg.count('fill="#d62728"') == 1
    assert 'data-points="0"' in latency_psnr_svg([], None)


def test_stats_text_lists_stages_share_and_psnr():
    import numpy as np

    z = np.zeros((2, 2, 3), np.uint8)
    f = Frame("imls", z, np.zeros((2, 2), bool), z, {"importance": 1.0, "total": 5.5}, 0.25, 31.25, 0.4)
    text = stats_text(f)
    assert re.search(r"importance\s+1.0 ms", text) and re.search(r"total\s+5.5 ms", text)
    assert "25.0 %" in text and "31.25 dB" in text and "0.400" in text


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _serve(args: list[str], port: int, tmp_path: Path):
    pytest.importorskip("trame", reason="the web extra is not installed (pip install -e '.[web]')")
    log = open(tmp_path / "web.log", "w")
    p = subprocess.Popen([sys.executable, "-m", "imls_lightning.web", *args, f"port={port}", "host=127.0.0.1"],
                         cwd=ROOT, stdout=log, stderr=subprocess.STDOUT, env=dict(os.environ, PYTHONUNBUFFERED="1"))
    url = f"http://127.0.0.1:{port}/"
    for _ in range(600):
        try:
            with urllib.request.urlopen(url, timeout=1) as r:
                if r.status == 200:
                    return p, url
        except OSError:
            time.sleep(0.1)
        if p.poll() is not None:
            break
    p.kill()
    pytest.fail(f"the web viewer did not start: {(tmp_path / 'web.log').read_text()[-2000:]}")


def test_smoke_server_serves_the_page_on_localhost(tiny_checkpoints, tmp_path):
    p, url = _serve([f"ims_checkpoint={tiny_checkpoints['ims_pim']}"], _free_port(), tmp_path)
    try:
        with urllib.request.urlopen(url, timeout=5) as r:
            assert r.status == 200 and b"<html" in r.read().lower()
        time.sleep(1.0)
        assert p.poll() is None
        assert "serving http://127.0.0.1:" in (tmp_path / "web.log").read_text()
    finally:
        p.terminate()
        p.wait(10)


def test_exception_cli_without_checkpoint_is_one_line():
    p = subprocess.run([sys.executable, "-m", "imls_lightning.web"], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert p.returncode != 0 and "ims_checkpoint" in p.stderr


def test_selenium_manager_is_told_to_send_no_statistics():
    """Selenium Manager (run by ``webdriver.Chrome`` where it looks for a driver) otherwise sends usage
    statistics to an outside host; ``conftest.py`` sets this for every test here."""
    assert os.environ.get("SE_AVOID_STATS") == "true"


def _chrome():
    webdriver = pytest.importorskip("selenium.webdriver", reason="selenium is not installed (pip install -e '.[dev]')")
    chromium = shutil.which("chromium") or shutil.which("chromium-browser")
    driver = shutil.which("chromedriver")
    if not chromium or not driver:
        pytest.skip("Chromium or ChromeDriver not found (make test-browser installs Debian's chromium and chromium-driver)")
    from selenium.webdriver.chrome.options import Options
    from selenium.webdriver.chrome.service import Service

    opts = Options()
    opts.binary_location = chromium
    for a in ("--headless=new", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage", "--window-size=1400,1000"):
        opts.add_argument(a)
    return webdriver.Chrome(service=Service(driver), options=opts)


def _wait(cond, what: str, timeout: float = 60.0):
    t0 = time.time()
    while time.time() - t0 < timeout:
        try:
            v = cond()
        except Exception:  # the page is still being built (no such element yet)
            v = None
        if v:
            return v
        time.sleep(0.1)
    pytest.fail(f"timed out waiting for {what}")


def test_browser_orbit_slider_and_method_change_the_page(tiny_checkpoints, tmp_path):
    browser = _chrome()
    p, url = _serve([f"ims_checkpoint={tiny_checkpoints['ims_pim']}", f"las_checkpoint={tiny_checkpoints['las']}"],
                    _free_port(), tmp_path)
    ARTIFACTS.mkdir(parents=True, exist_ok=True)
    try:
        from selenium.webdriver.common.action_chains import ActionChains
        from selenium.webdriver.common.by import By
        from selenium.webdriver.common.keys import Keys

        def frames() -> int:
            t = browser.find_element(By.ID, "frames").get_attribute("textContent").strip()
            return int(t) if t.isdigit() else 0

        def src(el_id: str) -> str:
            return browser.find_element(By.ID, el_id).get_attribute("src") or ""

        browser.get(url)
        _wait(lambda: frames() >= 1 and src("frame").startswith("data:image/png"), "the first frame")
        stats0, image0, n = browser.find_element(By.ID, "stats").text, src("frame"), frames()
        assert "PSNR" in stats0 and "total" in stats0 and "pixels ray-cast" in stats0
        browser.save_screenshot(str(ARTIFACTS / "web_first_frame.png"))

        # a synthetic drag orbits the camera: a new frame with another image
        frame = browser.find_element(By.ID, "frame")
        ActionChains(browser).move_to_element(frame).click_and_hold().move_by_offset(40, 0).move_by_offset(40, 10).release().perform()
        _wait(lambda: frames() > n and src("frame") != image0, "a frame after the drag")
        browser.save_screenshot(str(ARTIFACTS / "web_after_drag.png"))

        # the share slider: keyboard steps on the thumb change the share of C, the pixels ray-cast and the figures
        mask0, n = src("mask"), frames()
        thumb = browser.find_element(By.CSS_SELECTOR, "#share-slider .v-slider-thumb, .v-slider-thumb")
        thumb.click()
        for _ in range(30):
            thumb.send_keys(Keys.ARROW_RIGHT)
        _wait(lambda: frames() > n and src("mask") != mask0, "a frame at the new share")
        assert browser.find_element(By.ID, "stats").text != stats0
        assert int(re.search(r'data-points="(\d+)"', browser.find_element(By.ID, "plot").get_attribute("innerHTML")).group(1)) >= 2

        # the method: the ground truth scores exact
        browser.find_element(By.CSS_SELECTOR, "#method-select, .v-select").click()
        _wait(lambda: [o for o in browser.find_elements(By.CSS_SELECTOR, ".v-list-item") if "Ground truth" in o.text], "the method list")[0].click()
        _wait(lambda: "(exact)" in browser.find_element(By.ID, "stats").text, "the ground truth's stats")
        browser.save_screenshot(str(ARTIFACTS / "web_ground_truth.png"))
        assert browser.find_element(By.ID, "error").get_attribute("textContent").strip() == ""
    finally:
        browser.quit()
        p.terminate()
        p.wait(10)


def test_browser_bad_checkpoint_shows_a_message_in_the_page(tiny_checkpoints, tmp_path):
    browser = _chrome()
    p, url = _serve([f"ims_checkpoint={tiny_checkpoints['recnn']}"], _free_port(), tmp_path)
    try:
        from selenium.webdriver.common.by import By

        browser.get(url)
        msg = _wait(lambda: browser.find_element(By.ID, "error").get_attribute("textContent").strip(), "the error message")
        assert msg.startswith("ims_checkpoint=") and "RecNNTask" in msg
        assert "error: ims_checkpoint=" in (tmp_path / "web.log").read_text()
    finally:
        browser.quit()
        p.terminate()
        p.wait(10)
