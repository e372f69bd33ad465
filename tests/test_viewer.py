"""The browser viewer in a real browser: ``hydroarm view`` served on a loopback port, driven by headless
Chromium (Debian's /usr/bin/chromium through Playwright, the network blocked apart from loopback).

The arm is drawn where the viewer's camera projects it (pixels of the link's colour at the projected
midpoint of its longest cylinder), and moving the time slider moves it. ``HYDROARM_SAVE_FIGURES=1``
also writes the two screenshots to docs/figures/ (viewer_t0.png, viewer_t5.png).
"""

from __future__ import annotations

import colorsys
import os
import re
import shutil
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

CHROMIUM = "/usr/bin/chromium"
CHROMIUM_ARGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--no-first-run",
    "--host-resolver-rules=MAP * ~NOTFOUND, EXCLUDE localhost, EXCLUDE 127.0.0.1",
]
LOCAL = ("http://127.0.0.1", "ws://127.0.0.1", "data:", "blob:")

pytestmark = [pytest.mark.subprocess, pytest.mark.slow]


def _requirements():
    if not Path(CHROMIUM).is_file():
        pytest.skip(f"{CHROMIUM} is missing (apt-get install chromium)")
    pytest.importorskip("playwright.sync_api", reason="playwright is missing (pip install -e '.[viewer]')")
    pytest.importorskip("viser", reason="viser is missing (pip install -e '.[viewer]')")


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def _wait_port(port: int, process: subprocess.Popen, timeout: float = 60.0) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if process.poll() is not None:
            raise AssertionError(f"hydroarm view exited with {process.returncode}: {process.stdout.read()}")
        with socket.socket() as sock:
            if sock.connect_ex(("127.0.0.1", port)) == 0:
                return
        time.sleep(0.1)
    raise AssertionError(f"nothing listens on port {port} after {timeout} s")


def link_colour_near(image: np.ndarray, xy: np.ndarray, rgb: tuple[int, int, int], half: int = 5) -> bool:
    """Whether some pixel within ``half`` px of ``xy`` has the hue of ``rgb`` (shading changes only its value)."""
    hue = colorsys.rgb_to_hsv(*(c / 255.0 for c in rgb))[0]
    x, y = int(round(xy[0])), int(round(xy[1]))
    patch = image[max(y - half, 0) : y + half + 1, max(x - half, 0) : x + half + 1, :3] / 255.0
    for r, g, b in patch.reshape(-1, 3):
        h, s, v = colorsys.rgb_to_hsv(r, g, b)
        if s > 0.3 and v > 0.15 and min(abs(h - hue), 1.0 - abs(h - hue)) < 0.04:
            return True
    return False


def _screenshot(page, path: Path) -> np.ndarray:
    from PIL import Image

    page.screenshot(path=str(path))
    return np.asarray(Image.open(path).convert("RGB"))


def _scene_canvas(page) -> dict:
    """The 3-D canvas (the largest canvas on the page; the plots are canvases too): x, y, width, height."""
    return page.evaluate(
        """() => { let best = null;
        for (const c of document.querySelectorAll('canvas')) { const r = c.getBoundingClientRect();
          if (!best || r.width * r.height > best.width * best.height)
            best = {x: r.x, y: r.y, width: r.width, height: r.height}; }
        return best; }"""
    )


def test_viewer_draws_the_arm_and_the_slider_moves_it(tmp_path):
    _requirements()
    from playwright.sync_api import sync_playwright

    from hydroarm.sim.experiment import ExperimentConfig, run_experiment
    from hydroarm.studies.playback import reach
    from hydroarm.studies.viewer import camera_for, cylinder_poses, link_colour

    traj = run_experiment(ExperimentConfig(), "gp-mpc", seed=0)  # 10 s, 1000 steps
    run_file = traj.save(tmp_path / "run.npz")
    from hydroarm.model.loading import load_arm

    arm = load_arm(traj.meta.get("arm", "paper"))
    camera = camera_for(reach(arm, np.concatenate([traj.q, traj.q_ref])))
    moving = [i for i, c in enumerate(arm.cylinders) if c.joint_id > 0]
    index = max(moving, key=lambda i: cylinder_poses(arm, traj.q[0])[2][i])  # the longest link cylinder
    rgb = link_colour(arm, index)

    port = _free_port()
    command = [sys.executable, "-m", "hydroarm.cli", "view", str(run_file), "--no-browser", "--port", str(port)]
    process = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    blocked: list[str] = []
    try:
        _wait_port(port, process)
        with sync_playwright() as playwright:
            browser = playwright.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
            page = browser.new_page(viewport={"width": 1280, "height": 720})

            def route(request_route):
                if request_route.request.url.startswith(LOCAL):
                    return request_route.continue_()
                blocked.append(request_route.request.url)
                return request_route.abort()

            page.route("**/*", route)
            page.goto(f"http://127.0.0.1:{port}/")
            page.wait_for_selector("canvas", timeout=30_000)

            def arm_at(k: int, name: str) -> tuple[np.ndarray, np.ndarray]:
                """Screenshots until the longest link shows at its projection at sample k (30 s at most)."""
                deadline = time.monotonic() + 30.0
                while True:
                    box = _scene_canvas(page)
                    centre = cylinder_poses(arm, traj.q[k])[0][index]
                    xy = camera.project(centre, box["width"], box["height"]) + (box["x"], box["y"])
                    image = _screenshot(page, tmp_path / name)
                    if link_colour_near(image, xy, rgb):
                        return image, xy
                    assert time.monotonic() < deadline, f"the arm is not drawn at {xy} (t = {traj.t[k]} s): {name}"
                    page.wait_for_timeout(200)

            first, xy0 = arm_at(0, "viewer_t0.png")
            # move the time slider: click its track at 5 s, then read the time it settled on
            track = page.locator(".mantine-Slider-root").first
            box = track.bounding_box()
            page.mouse.click(box["x"] + box["width"] * 5.0 / float(traj.t[-1]), box["y"] + box["height"] / 2)
            page.wait_for_timeout(300)
            shown = page.get_by_text(re.compile(r"^t = [0-9.]+ s,")).inner_text()  # the viewer's clock
            value = float(re.match(r"t = ([0-9.]+) s", shown).group(1))
            assert abs(value - 5.0) < 0.2, value
            k = int(np.argmin(np.abs(traj.t - value)))
            second, xy5 = arm_at(k, "viewer_t5.png")
            browser.close()
    finally:
        process.terminate()
        process.wait(timeout=30)
    assert not blocked, f"the page asked the internet for {blocked}"
    assert np.linalg.norm(xy5 - xy0) > 10.0, "the arm should have moved on screen between t = 0 and 5 s"
    for xy in (xy0, xy5):  # where the arm was and where it is, the two screenshots differ
        x, y = int(xy[0]), int(xy[1])
        assert np.any(first[y - 4 : y + 5, x - 4 : x + 5] != second[y - 4 : y + 5, x - 4 : x + 5])
    assert not link_colour_near(second, xy0, rgb, half=2) or not link_colour_near(first, xy5, rgb, half=2)
    if os.environ.get("HYDROARM_SAVE_FIGURES"):
        figures = Path(__file__).resolve().parents[1] / "docs" / "figures"
        for name in ("viewer_t0.png", "viewer_t5.png"):
            shutil.copy(tmp_path / name, figures / name)
