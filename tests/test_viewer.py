"""The browser viewer: its charts, its vehicle scene and its recording, and the viewer in a real browser
(``hydroarm view`` served on a loopback port, driven by headless Chromium: Debian's /usr/bin/chromium
through Playwright, the network blocked apart from loopback).

In the browser, the arm is drawn where the viewer's camera projects it (pixels of the link's colour at
the projected midpoint of its longest cylinder), and moving the time slider moves it; on a vehicle run
the arm sits on the moving base, under the hull. The charts have their width when they enter the page
(before any paint) and their time cursor sits where the chart's own time axis puts the shown time.
``HYDROARM_SAVE_FIGURES=1`` also writes the screenshots to docs/figures/ (viewer_t0.png, viewer_t5.png,
viewer_vehicle.png, viewer_recording.png).
"""

from __future__ import annotations

import colorsys
import contextlib
import os
import re
import shutil
import socket
import subprocess
import sys
import time
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest

from hydroarm.model.arm.loading import load_arm
from hydroarm.sim.experiment import ExperimentConfig, build_experiment, run_experiment
from hydroarm.sim.runner import Trajectory
from hydroarm.sim.vehicle import VehicleRun
from hydroarm.studies.playback import VehicleMotion, reach, rotation, vehicle_motion
from hydroarm.studies.viewer_charts import LEFT, MOST_POINTS, PLOT_WIDTH, WIDTH, Chart, Series, nice_ticks

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

BROWSER = [pytest.mark.subprocess, pytest.mark.slow]


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
    """The 3-D canvas (the largest canvas on the page): x, y, width, height."""
    return page.evaluate(
        """() => { let best = null;
        for (const c of document.querySelectorAll('canvas')) { const r = c.getBoundingClientRect();
          if (!best || r.width * r.height > best.width * best.height)
            best = {x: r.x, y: r.y, width: r.width, height: r.height}; }
        return best; }"""
    )


# a MutationObserver noting, as each chart enters the page (before the browser paints it), its width
CHART_WIDTHS_AT_INSERTION = """
window.__hydroarmChartWidths = [];
new MutationObserver((records) => {
  for (const record of records) for (const node of record.addedNodes) {
    if (!node.querySelectorAll) continue;
    for (const chart of node.querySelectorAll('.hydroarm-chart'))
      if (chart.isConnected)
        window.__hydroarmChartWidths.push([chart.dataset.chart, chart.getBoundingClientRect().width]);
  }
}).observe(document, {childList: true, subtree: true});
"""


@pytest.fixture(scope="module")
def arm_run(tmp_path_factory) -> Path:
    """A 10 s GP-MPC run of the paper arm (1000 steps), saved."""
    return run_experiment(ExperimentConfig(), "gp-mpc", seed=0).save(tmp_path_factory.mktemp("arm") / "run.npz")


@pytest.fixture(scope="module")
def vehicle_run(tmp_path_factory) -> Path:
    """3 s of the Alpha 5 on the BlueROV2 holding station in the 0.2 m/s current (``hydroarm run --vehicle
    bluerov2-heavy --set duration=3`` in Python), saved."""
    config = ExperimentConfig(arm="mount", vehicle=VehicleRun(name="bluerov2_heavy"), duration=3.0)
    return build_experiment(config, "smc").run().save(tmp_path_factory.mktemp("vehicle") / "run.npz")


@pytest.fixture(scope="module")
def moved_vehicle_run(vehicle_run, tmp_path_factory) -> Path:
    """The vehicle run with its base poses replaced by a known motion large enough to see on screen:
    0.3 m along x and 40 deg of yaw over the run (the station keeper holds the real one to a few cm)."""
    traj = Trajectory.load(vehicle_run)
    fraction = np.linspace(0.0, 1.0, len(traj.t))
    yaw = np.radians(40.0) * fraction
    poses = np.zeros((len(traj.t), 7))
    poses[:, 0] = 0.3 * fraction
    poses[:, 5], poses[:, 6] = np.sin(yaw / 2.0), np.cos(yaw / 2.0)
    traj.extra["base_pose"] = poses
    return traj.save(tmp_path_factory.mktemp("moved") / "run.npz")


def _series(n: int = 400) -> tuple[np.ndarray, np.ndarray]:
    t = 0.01 * np.arange(n)
    return t, np.sin(2.0 * t) * 3.0 + 0.5 * t


def _parse(svg: str) -> ET.Element:
    return ET.fromstring(svg)


def _path_points(path: ET.Element) -> np.ndarray:
    """The (x, y) vertices of an SVG path made of M and implicit line-to pairs."""
    return np.array([[float(v) for v in pair.split(",")] for pair in path.get("d").replace("M", " ").split()])


def _y_axis(root: ET.Element) -> tuple[float, float]:
    """(value per viewBox unit, value at y = 0) read off the chart's own y tick labels and lines."""
    ticks = [
        (float(text.get("y")) - 3.5, float(text.text))
        for text in root.iter("text")
        if text.get("text-anchor") == "end" and text.text not in ("t (s)",)
    ]
    (y0, v0), (y1, v1) = ticks[0], ticks[-1]
    slope = (v1 - v0) / (y1 - y0)
    return slope, v0 - slope * y0


def test_nice_ticks_are_round_and_span_the_range():
    assert np.allclose(nice_ticks(-0.012, 0.03), [-0.01, 0.0, 0.01, 0.02, 0.03])
    assert np.allclose(nice_ticks(0.0, 9.99), [0, 2, 4, 6, 8])
    assert np.allclose(nice_ticks(-550.0, 550.0), [-400, -200, 0, 200, 400])
    for low, high in ((-1.3, 3.9), (0.0, 60.0), (1e-4, 7e-4), (-3e3, -1e3)):
        ticks = nice_ticks(low, high)
        step = np.diff(ticks)
        assert np.all(ticks >= low) and np.all(ticks <= high) and 3 <= len(ticks) <= 8
        mantissa = step[0] / 10.0 ** np.floor(np.log10(step[0]))
        assert np.allclose(step, step[0]) and min(abs(mantissa - m) for m in (1, 2, 5)) < 1e-9


def test_a_chart_draws_its_data_where_its_own_axes_say():
    """Each vertex of the drawn line, read back through the chart's tick labels, is the data."""
    t, values = _series()
    chart = Chart(t)
    root = _parse(chart.svg("test", "title", [Series("a", values, "rgb(1,2,3)")]))
    (path,) = [p for p in root.iter("path") if p.get("stroke") == "rgb(1,2,3)"]
    points = _path_points(path)
    assert len(points) == len(t)
    assert np.allclose(points[:, 0], LEFT + (t - t[0]) / (t[-1] - t[0]) * PLOT_WIDTH, atol=0.05)  # printed to 0.1
    slope, offset = _y_axis(root)
    # the vertices and the tick positions are printed to 0.1 viewBox units: 0.1 units of error at most
    assert np.allclose(points[:, 1] * slope + offset, values, atol=0.1 * abs(slope))


def test_a_long_series_keeps_every_columns_extremes():
    """Beyond MOST_POINTS samples a line keeps each column's min and max: the drawn extremes are the data's."""
    rng = np.random.default_rng(0)
    t = 0.001 * np.arange(20_000)
    values = np.cumsum(rng.normal(size=t.size))
    values[[1234, 15000]] = values.max() + 50.0, values.min() - 50.0  # two one-sample spikes
    values[5000:5100] = np.nan  # a gap
    root = _parse(Chart(t).svg("long", "title", [Series("a", values, "rgb(1,2,3)")]))
    (path,) = [p for p in root.iter("path") if p.get("stroke") == "rgb(1,2,3)"]
    points = _path_points(path)
    assert len(points) <= MOST_POINTS and path.get("d").count("M") == 2  # the gap splits the line
    slope, offset = _y_axis(root)
    drawn = points[:, 1] * slope + offset
    tolerance = 0.1 * abs(slope)  # printed to 0.1 viewBox units, as above
    assert abs(drawn.max() - np.nanmax(values)) < tolerance and abs(drawn.min() - np.nanmin(values)) < tolerance


def test_the_cursor_offset_follows_the_charts_time_axis():
    t, _ = _series()
    chart = Chart(t + 2.0)
    assert chart.cursor_offset(2.0) == 0.0 and chart.cursor_offset(2.0 + t[-1]) == pytest.approx(PLOT_WIDTH)
    assert chart.cursor_offset(2.0 + t[-1] / 4.0) == pytest.approx(PLOT_WIDTH / 4.0)
    assert chart.cursor_offset(-5.0) == 0.0 and chart.cursor_offset(99.0) == PLOT_WIDTH  # held within the plot
    root = _parse(chart.svg("c", "title", [Series("a", t, "red")]))
    (cursor,) = [line for line in root.iter("line") if line.get("class") == "hydroarm-cursor"]
    assert float(cursor.get("x1")) == LEFT and "--hydroarm-cursor-x" in cursor.get("style")


def test_the_vehicle_motion_agrees_with_pinocchio(tmp_path):
    """Quaternion to rotation, the arm's mounted frame and roll-pitch-yaw, against Pinocchio's own."""
    import pinocchio as pin

    from hydroarm.model.vehicle.description import load_vehicle

    vehicle = load_vehicle("bluerov2-heavy")
    saved, poses = _saved_with_random_poses(np.random.default_rng(1), tmp_path)
    motion = vehicle_motion(Trajectory.load(saved))
    assert isinstance(motion, VehicleMotion)
    attitude = motion.attitude_deg()
    for k, pose in enumerate(poses):
        placement = pin.XYZQUATToSE3(pose)
        assert np.allclose(rotation(pose[3:]), placement.rotation, atol=1e-12)
        turn, origin = motion.arm_frame(pose)
        mounted = placement * vehicle.mount
        assert np.allclose(turn, mounted.rotation, atol=1e-12) and np.allclose(origin, mounted.translation)
        assert np.allclose(np.radians(attitude[k]), pin.rpy.matrixToRpy(placement.rotation), atol=1e-9)
    corners = motion.corners(poses[0])
    assert np.allclose(np.linalg.norm(corners - poses[0, :3], axis=1), np.linalg.norm(vehicle.hull / 2.0))


def _saved_with_random_poses(rng: np.random.Generator, folder: Path) -> tuple[Path, np.ndarray]:
    """A short vehicle run (0.2 s) saved with random base poses (K, 7) in place of its own."""
    config = ExperimentConfig(arm="mount", vehicle=VehicleRun(name="bluerov2_heavy"), duration=0.2)
    traj = build_experiment(config, "smc").run()
    poses = np.column_stack([rng.normal(size=(len(traj.t), 3)), rng.normal(size=(len(traj.t), 4))])
    poses[:, 3:] /= np.linalg.norm(poses[:, 3:], axis=1, keepdims=True)
    traj.extra["base_pose"] = poses
    return traj.save(folder / "run.npz"), poses


def test_the_viewer_mounts_the_arm_on_the_hull_and_moves_it_with_the_base(vehicle_run, arm_run):
    """Vehicle run: the hull and the mount under ``/vehicle``, placed at the base pose of the shown
    sample; fixed-base run: no vehicle node, the arm at the scene's root."""
    pytest.importorskip("viser")
    from hydroarm.studies.viewer import TrajectoryViewer

    with contextlib.redirect_stdout(None):
        viewer = TrajectoryViewer(vehicle_run, port=_free_port())
    try:
        scene, poses = viewer.scene, viewer.vehicle.poses
        assert scene.hull.name == "/vehicle/hull" and np.allclose(scene.hull.dimensions, 2.0 * viewer.vehicle.half)
        assert all(handle.name.startswith("/vehicle/mount/arm/") for handle in scene.solid)
        for k in (0, len(poses) - 1):
            viewer.show_time(float(viewer.traj.t[k]))
            assert np.allclose(scene.base.position, poses[k, :3])
            assert np.allclose(scene.base.wxyz, poses[k, [6, 3, 4, 5]])
    finally:
        viewer.stop()
    with contextlib.redirect_stdout(None):
        fixed = TrajectoryViewer(arm_run, port=_free_port())
    try:
        assert fixed.vehicle is None and fixed.scene.hull is None and fixed.scene.base is None
        assert all(handle.name.startswith("/arm/") for handle in fixed.scene.solid)
    finally:
        fixed.stop()


def test_the_recording_carries_the_charts_of_every_joint(vehicle_run, arm_run, tmp_path):
    pytest.importorskip("viser")
    from hydroarm.studies.viewer import write_html

    for run, joints, vehicle in ((arm_run, 6, False), (vehicle_run, 4, True)):
        page = write_html(run, tmp_path / "run.html").read_text()
        charts = set(re.findall(r'class="hydroarm-chart" data-chart="([a-z0-9-]+)"', page))
        expected = {"error"} | {f"{kind}-{j}" for kind in ("torque", "disturbance") for j in range(1, joints + 1)}
        assert charts == expected | ({"drift", "attitude"} if vehicle else set())
        assert page.count('id="hydroarm-panel"') == 1 and page.index('id="hydroarm-panel"') > page.index('id="root"')


@pytest.mark.parametrize("damage", ["vehicle", "poses"])
def test_a_vehicle_run_the_viewer_cannot_draw_is_one_line_and_exit_2(vehicle_run, tmp_path, damage):
    """A run naming a vehicle that does not load, or base poses that do not match its samples."""
    pytest.importorskip("viser")
    from typer.testing import CliRunner

    from hydroarm.cli import app

    traj = Trajectory.load(vehicle_run)
    if damage == "vehicle":
        traj.meta["vehicle"] = str(tmp_path / "gone.toml")
    else:
        traj.extra["base_pose"] = traj.extra["base_pose"][:-1]
    run = traj.save(tmp_path / "run.npz")
    result = CliRunner().invoke(app, ["view", str(run), "--out", str(tmp_path / "run.html")])
    lines = result.output.strip().splitlines()
    assert result.exit_code == 2 and len(lines) == 1 and lines[0].startswith("error:"), result.output
    assert ("gone.toml" if damage == "vehicle" else "base_pose") in lines[0], lines[0]
    assert not (tmp_path / "run.html").exists()


def _open(playwright, url: str, blocked: list[str], init_script: str | None = None):
    """A headless page at ``url``: every request outside loopback (and ``url`` itself) is blocked and noted."""
    browser = playwright.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
    page = browser.new_page(viewport={"width": 1280, "height": 720})
    if init_script:
        page.add_init_script(init_script)

    def route(request_route):
        if request_route.request.url.startswith((*LOCAL, url)):
            return request_route.continue_()
        blocked.append(request_route.request.url)
        return request_route.abort()

    page.route("**/*", route)
    page.goto(url)
    return browser, page


@contextlib.contextmanager
def _served(run_file: Path):
    port = _free_port()
    command = [sys.executable, "-m", "hydroarm.cli", "view", str(run_file), "--no-browser", "--port", str(port)]
    process = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        _wait_port(port, process)
        yield f"http://127.0.0.1:{port}/"
    finally:
        process.terminate()
        process.wait(timeout=30)


def _cursors(page) -> list[dict]:
    """Every chart's box and its cursor's x (px), from the page."""
    return page.evaluate(
        """() => [...document.querySelectorAll('.hydroarm-chart')].filter(c => c.getClientRects().length)
          .map(c => { const r = c.getBoundingClientRect();
            return {chart: c.dataset.chart, x: r.x, width: r.width,
                    cursor: c.querySelector('.hydroarm-cursor').getBoundingClientRect().x}; })"""
    )


def _cursor_at(charts: list[dict], time_s: float, t0: float, t1: float) -> None:
    """Every cursor sits where its chart's time axis puts ``time_s`` (to a pixel)."""
    for chart in charts:
        expected = chart["x"] + (LEFT + (time_s - t0) / (t1 - t0) * PLOT_WIDTH) / WIDTH * chart["width"]
        assert abs(chart["cursor"] - expected) < 1.0, (chart, time_s, expected)


def _slider_time(page) -> float:
    shown = page.get_by_text(re.compile(r"^t = [0-9.]+ s,")).inner_text()  # the viewer's clock
    return float(re.match(r"t = ([0-9.]+) s", shown).group(1))


def _chart_drawn(image: np.ndarray, box: dict, rgb: tuple[int, int, int]) -> bool:
    """Whether the line colour ``rgb`` shows inside the chart's ``box`` of a screenshot."""
    x0, y0 = int(box["x"]), int(box["y"])
    patch = image[y0 : y0 + int(box["height"]), x0 : x0 + int(box["width"])].astype(int)
    return bool(np.any(np.all(np.abs(patch - np.array(rgb)) < 40, axis=-1)))


@pytest.mark.subprocess
@pytest.mark.slow
def test_viewer_draws_the_arm_the_charts_and_the_cursor_follows_the_slider(tmp_path, arm_run):
    _requirements()
    from playwright.sync_api import sync_playwright

    from hydroarm.studies.viewer import LINK_RGB, camera_for, cylinder_poses, link_colour

    traj = Trajectory.load(arm_run)
    arm = load_arm(traj.meta.get("arm", "paper"))
    camera = camera_for(reach(arm, np.concatenate([traj.q, traj.q_ref])))
    moving = [i for i, c in enumerate(arm.cylinders) if c.joint_id > 0]
    index = max(moving, key=lambda i: cylinder_poses(arm, traj.q[0])[2][i])  # the longest link cylinder
    rgb = link_colour(arm, index)
    t0, t1 = float(traj.t[0]), float(traj.t[-1])
    blocked: list[str] = []
    with _served(arm_run) as url, sync_playwright() as playwright:
        browser, page = _open(playwright, url, blocked, CHART_WIDTHS_AT_INSERTION)
        page.wait_for_selector(".hydroarm-chart", timeout=60_000)
        first = _screenshot(page, tmp_path / "first.png")  # at once: the charts are already drawn
        boxes = page.evaluate(
            "() => [...document.querySelectorAll('.hydroarm-chart')].map(c => c.getBoundingClientRect().toJSON())"
        )
        assert boxes and all(box["width"] > 200 for box in boxes), boxes
        assert _chart_drawn(first, boxes[0], LINK_RGB[0]), "the joint errors are not drawn in the first screenshot"
        widths = page.evaluate("window.__hydroarmChartWidths")
        assert widths and all(width == pytest.approx(boxes[0]["width"]) for _, width in widths), widths
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
        _cursor_at(_cursors(page), 0.0, t0, t1)
        # move the time slider: click its track at 5 s, then read the time it settled on
        track = page.locator(".mantine-Slider-root").first
        box = track.bounding_box()
        page.mouse.click(box["x"] + box["width"] * 5.0 / t1, box["y"] + box["height"] / 2)
        page.wait_for_timeout(300)
        value = _slider_time(page)
        assert abs(value - 5.0) < 0.2, value
        k = int(np.argmin(np.abs(traj.t - value)))
        second, xy5 = arm_at(k, "viewer_t5.png")
        _cursor_at(_cursors(page), float(traj.t[k]), t0, t1)
        tree = page.evaluate("() => Object.keys(window.__viserSceneTree.getState())")
        browser.close()
    assert not blocked, f"the page asked the internet for {blocked}"
    assert not any(name.startswith("/vehicle") for name in tree), tree
    assert np.linalg.norm(xy5 - xy0) > 10.0, "the arm should have moved on screen between t = 0 and 5 s"
    for xy in (xy0, xy5):  # where the arm was and where it is, the two screenshots differ
        x, y = int(xy[0]), int(xy[1])
        assert np.any(first[y - 4 : y + 5, x - 4 : x + 5] != second[y - 4 : y + 5, x - 4 : x + 5])
    assert not link_colour_near(second, xy0, rgb, half=2) or not link_colour_near(first, xy5, rgb, half=2)
    _save_figures(tmp_path, "viewer_t0.png", "viewer_t5.png")


def _save_figures(folder: Path, *names: str) -> None:
    if os.environ.get("HYDROARM_SAVE_FIGURES"):
        figures = Path(__file__).resolve().parents[1] / "docs" / "figures"
        for name in names:
            shutil.copy(folder / name, figures / name)


@pytest.mark.subprocess
@pytest.mark.slow
@pytest.mark.parametrize("motion", ["held", "moved"])
def test_viewer_draws_the_arm_on_the_moving_vehicle(tmp_path, request, motion):
    """The hull is in the scene, its frame at the base pose of the shown sample, and the arm is drawn on
    its mount where that pose puts it: for the run as simulated ("held", a few cm of drift) and for a
    base moved 0.3 m and turned 40 deg over the run ("moved"), where the arm must move on screen."""
    _requirements()
    from playwright.sync_api import sync_playwright

    from hydroarm.studies.viewer import camera_for, cylinder_poses, link_colour, scene_extent

    run_file = request.getfixturevalue({"held": "vehicle_run", "moved": "moved_vehicle_run"}[motion])
    traj = Trajectory.load(run_file)
    arm = load_arm(traj.meta["arm"])
    vehicle = vehicle_motion(traj)
    camera = camera_for(scene_extent(traj, arm, vehicle), vehicle.target)
    index = max((i for i, c in enumerate(arm.cylinders) if c.joint_id > 0), key=lambda i: arm.cylinders[i].length)
    rgb = link_colour(arm, index)

    def projected(k: int, box: dict, mounted: bool = True) -> np.ndarray:
        turn, origin = vehicle.arm_frame(vehicle.poses[k]) if mounted else (np.eye(3), np.zeros(3))
        centre = turn @ cylinder_poses(arm, traj.q[k])[0][index] + origin
        return camera.project(centre, box["width"], box["height"]) + (box["x"], box["y"])

    blocked: list[str] = []
    drawn, unmounted, base = {}, {}, {}
    with _served(run_file) as url, sync_playwright() as playwright:
        browser, page = _open(playwright, url, blocked)
        page.wait_for_selector("canvas", timeout=60_000)
        for fraction in (0.0, 0.5 if motion == "held" else 1.0):
            if fraction:
                box = page.locator(".mantine-Slider-root").first.bounding_box()
                page.mouse.click(box["x"] + (box["width"] - 1) * fraction, box["y"] + box["height"] / 2)
                page.wait_for_timeout(300)
            k = int(np.argmin(np.abs(traj.t - _slider_time(page))))
            deadline = time.monotonic() + 30.0
            while True:
                canvas = _scene_canvas(page)
                xy = projected(k, canvas)
                image = _screenshot(page, tmp_path / "viewer_vehicle.png")
                if link_colour_near(image, xy, rgb):
                    break
                assert time.monotonic() < deadline, f"the arm is not drawn on the vehicle at {xy} (sample {k})"
                page.wait_for_timeout(200)
            drawn[k], unmounted[k] = xy, projected(k, canvas, mounted=False)
            base[k] = page.evaluate("() => window.__viserMutable.nodePoseData['/vehicle']")
        nodes = page.evaluate(
            "() => Object.fromEntries(Object.entries(window.__viserSceneTree.getState())"
            ".map(([name, node]) => [name, node.message ? node.message.type : null]))"
        )
        browser.close()
    assert not blocked, f"the page asked the internet for {blocked}"
    assert nodes.get("/vehicle/hull") == "BoxMessage" and nodes.get("/vehicle/mount") == "FrameMessage", nodes
    assert len(drawn) == 2, drawn
    for k, xy in drawn.items():
        assert np.allclose(base[k]["position"], vehicle.poses[k, :3], atol=1e-6), (k, base[k])
        assert np.allclose(base[k]["wxyz"], vehicle.poses[k, [6, 3, 4, 5]], atol=1e-6), (k, base[k])
        assert np.linalg.norm(xy - unmounted[k]) > 30.0, "the arm's mount does not move it on screen: no test"
    if motion == "moved":
        first, last = drawn.values()
        assert np.linalg.norm(last - first) > 20.0, drawn
    else:
        _save_figures(tmp_path, "viewer_vehicle.png")


@pytest.mark.subprocess
@pytest.mark.slow
def test_the_recording_shows_its_charts_at_once_and_their_cursor_follows_the_playback(tmp_path, arm_run):
    """``chromium --headless --screenshot`` of ``view --out run.html`` (one shot, no waiting) shows the
    charts drawn; in the page, scrubbing the playback bar moves every cursor to the time it shows."""
    _requirements()
    from playwright.sync_api import sync_playwright

    from hydroarm.studies.viewer import LINK_RGB

    html = tmp_path / "run.html"
    done = subprocess.run(
        [sys.executable, "-m", "hydroarm.cli", "view", str(arm_run), "--out", str(html)],
        capture_output=True,
        text=True,
        check=True,
    )
    said = done.stdout + done.stderr
    assert said.startswith("wrote") and "http://" not in said and "Websocket" not in said, said  # no server banner
    shot = tmp_path / "oneshot.png"
    subprocess.run(
        [CHROMIUM, *CHROMIUM_ARGS, "--window-size=1280,720", f"--screenshot={shot}", html.as_uri()],
        capture_output=True,
        check=True,
        timeout=120,
        cwd=tmp_path,
    )
    from PIL import Image

    image = np.asarray(Image.open(shot).convert("RGB"))
    panel = {"x": 1280 - 400, "y": 0, "width": 400, "height": 720}  # recording.css: min(400px, 42vw) at the right
    for rgb in LINK_RGB[:6]:
        assert _chart_drawn(image, panel, rgb), f"joint colour {rgb} is not drawn in the one-shot screenshot"
    traj = Trajectory.load(arm_run)
    t0, t1 = float(traj.t[0]), float(traj.t[-1])
    blocked: list[str] = []
    with sync_playwright() as playwright:
        browser, page = _open(playwright, html.as_uri(), blocked)
        slider = page.wait_for_selector('#root [role="slider"][aria-valuenow]', state="attached", timeout=60_000)
        bar = page.locator(".mantine-Slider-root").first.bounding_box()
        seen = []
        for fraction in (0.25, 0.7):
            page.mouse.click(bar["x"] + bar["width"] * fraction, bar["y"] + bar["height"] / 2)  # pauses
            page.wait_for_timeout(300)
            recorded = float(slider.get_attribute("aria-valuenow"))  # the recording's time: t - t0
            assert abs(recorded - fraction * (t1 - t0)) < 0.1 * (t1 - t0), (fraction, recorded)
            charts = _cursors(page)
            _cursor_at(charts, t0 + recorded, t0, t1)
            seen.append(charts[0]["cursor"])
        page.wait_for_timeout(1000)  # the scene settles at the scrubbed time
        page.screenshot(path=str(tmp_path / "viewer_recording.png"))
        page.select_option("#hydroarm-joint", "2")  # joint 2
        shown = [c["chart"] for c in _cursors(page)]
        browser.close()
    assert not blocked, f"the page asked the internet for {blocked}"
    assert seen[1] - seen[0] > 100.0, seen
    assert shown == ["error", "torque-2", "disturbance-2"], shown  # joint 2's charts, and only those
    _save_figures(tmp_path, "viewer_recording.png")
