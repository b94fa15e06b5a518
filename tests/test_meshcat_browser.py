"""A `--record` run's meshcat.html opened in headless Chromium shows the scene, not a blank page.

Meshcat's empty scene already has a grey gradient background and a grid (hundreds of colours and a
pixel std of about 36 on an 800x600 screenshot), so colourfulness alone would pass for an empty
scene. What only the scene draws are dark pixels: the Stewart base, legs and the tag's black square
(the background never goes below about 75 of 255). The check counts those under the controls bar
and requires them near the middle of the view, where Meshcat's default camera puts the origin.
"""

import shutil
import subprocess

import cv2
import numpy as np
import pytest

from tests.conftest import landing_sim_command

CHROMIUM = shutil.which("chromium")
pytestmark = [pytest.mark.skipif(CHROMIUM is None, reason="chromium is not installed (make browser installs it)"),
              pytest.mark.slow]

WIDTH, HEIGHT = 800, 600
CONTROLS_BAR_ROWS = 30  # Meshcat's black "Open Controls" bar at the top right
DARK = 60  # 8-bit grey level below which only scene objects are drawn


@pytest.fixture(scope="module")
def screenshot(tmp_path_factory) -> np.ndarray:
    tmp = tmp_path_factory.mktemp("meshcat")
    out = tmp / "out"
    run = subprocess.run(landing_sim_command() + ["run", "stewart-hover", "--duration", "0.5", "--record",
                                                  "--out", str(out), "--quiet"],
                         capture_output=True, text=True, timeout=180)
    assert run.returncode == 0, run.stderr
    html = out / "meshcat.html"
    assert html.is_file() and html.stat().st_size > 100_000  # self-contained: three.js and the scene inlined
    png = tmp / "screenshot.png"
    browser = subprocess.run(
        [CHROMIUM, "--headless=new", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
         "--disable-component-update", "--no-first-run", "--disable-sync", "--use-angle=swiftshader",
         "--enable-unsafe-swiftshader", f"--user-data-dir={tmp / 'profile'}", f"--window-size={WIDTH},{HEIGHT}",
         "--virtual-time-budget=15000", f"--screenshot={png}", html.resolve().as_uri()],
        capture_output=True, text=True, timeout=120)
    assert png.is_file(), f"chromium wrote no screenshot (exit {browser.returncode}): {browser.stderr[-2000:]}"
    image = cv2.imread(str(png))
    assert image is not None
    return image


def test_screenshot_is_not_blank(screenshot):
    assert screenshot.shape == (HEIGHT, WIDTH, 3)
    grey = cv2.cvtColor(screenshot, cv2.COLOR_BGR2GRAY)
    packed = screenshot.reshape(-1, 3).astype(np.uint32) @ np.array([1, 256, 65536], np.uint32)
    colours = len(np.unique(packed))
    assert colours > 200, f"only {colours} distinct colours"
    assert grey.std() > 15, f"pixel std {grey.std():.1f}"


def test_the_scene_objects_stand_out_from_the_background(screenshot):
    grey = cv2.cvtColor(screenshot, cv2.COLOR_BGR2GRAY)[CONTROLS_BAR_ROWS:]
    rows, cols = np.nonzero(grey < DARK)
    assert len(rows) > 300, f"only {len(rows)} dark pixels: the platform was not drawn"
    # The platform stands at the origin, in the middle of Meshcat's default view.
    assert WIDTH / 4 < cols.mean() < 3 * WIDTH / 4
    assert HEIGHT / 6 < rows.mean() + CONTROLS_BAR_ROWS < 5 * HEIGHT / 6
