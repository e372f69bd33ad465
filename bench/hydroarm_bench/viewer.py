"""The browser viewer's speed: ``hydroarm view`` on a 10 s run (1000 steps) until the arm is drawn in
headless Chromium (software WebGL: no GPU here), the page opened as soon as the server listens
(as ``hydroarm view`` opens the browser), and the shareable recording (``hydroarm view --out
run.html``): time and size.

Skipped, with the reason, when the ``viewer`` extra (viser), playwright or /usr/bin/chromium is missing.
"""

from __future__ import annotations

import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

CHROMIUM = "/usr/bin/chromium"
ARGS = [
    "--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking", "--disable-component-update",
    "--disable-sync", "--no-first-run", "--host-resolver-rules=MAP * ~NOTFOUND, EXCLUDE localhost, EXCLUDE 127.0.0.1",
]  # fmt: skip


def _missing() -> str | None:
    try:
        import playwright.sync_api  # noqa: F401
        import viser  # noqa: F401
    except ImportError as error:
        return f"{error.name} is missing (pip install -e '.[test,viewer]')"
    return None if Path(CHROMIUM).is_file() else f"{CHROMIUM} is missing (apt-get install chromium)"


def _port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def _listening(port: int) -> bool:
    try:
        socket.create_connection(("127.0.0.1", port), timeout=0.1).close()
    except OSError:
        return False
    return True


def _drawn(page, camera, centre, rgb, shot: Path) -> bool:
    from PIL import Image

    box = page.evaluate(
        "() => { let b = null; for (const c of document.querySelectorAll('canvas')) {"
        " const r = c.getBoundingClientRect();"
        " if (!b || r.width * r.height > b.width * b.height) b = {x: r.x, y: r.y, width: r.width, height: r.height}; }"
        " return b; }"
    )
    if box is None:
        return False
    x, y = camera.project(centre, box["width"], box["height"]) + (box["x"], box["y"])
    page.screenshot(path=str(shot))
    patch = np.asarray(Image.open(shot).convert("RGB"))[int(y) - 5 : int(y) + 6, int(x) - 5 : int(x) + 6].reshape(-1, 3)
    return bool(np.any(np.all(np.abs(patch.astype(int) - np.array(rgb)) < 60, axis=1)))


def bench_viewer(quick: bool = False) -> dict:
    """Seconds from ``hydroarm view`` to the arm drawn, and the .html recording's time and size (10 s run)."""
    reason = _missing()
    if reason is not None:
        return {"skipped": reason}
    from playwright.sync_api import sync_playwright

    from hydroarm.model.arm.loading import load_arm
    from hydroarm.sim.experiment import ExperimentConfig, run_experiment
    from hydroarm.studies.playback import reach
    from hydroarm.studies.viewer import camera_for, cylinder_poses, link_colour

    folder = Path(tempfile.mkdtemp(prefix="hydroarm-viewer-bench-"))
    traj = run_experiment(ExperimentConfig(), "gp-mpc", seed=0)
    run_file = traj.save(folder / "run.npz")
    arm = load_arm(traj.meta.get("arm", "paper"))
    camera = camera_for(reach(arm, np.concatenate([traj.q, traj.q_ref])))
    index = max((i for i, c in enumerate(arm.cylinders) if c.joint_id > 0), key=lambda i: arm.cylinders[i].length)
    centre, rgb = cylinder_poses(arm, traj.q[0])[0][index], link_colour(arm, index)
    repeats = 1 if quick else 5
    open_s, html_s, listening_s = [], [], []
    html = folder / "run.html"
    with sync_playwright() as playwright:
        browser = playwright.chromium.launch(executable_path=CHROMIUM, args=ARGS)
        for _ in range(repeats):
            port = _port()
            page = browser.new_page(viewport={"width": 1280, "height": 720})
            started = time.perf_counter()
            process = subprocess.Popen(
                [sys.executable, "-m", "hydroarm.cli", "view", str(run_file), "--no-browser", "--port", str(port)],
                stdout=subprocess.DEVNULL,
                stderr=subprocess.DEVNULL,
            )
            try:
                # as `hydroarm view` does: the browser goes to the page once the server listens
                while not _listening(port):
                    assert process.poll() is None, "hydroarm view exited"
                    time.sleep(0.01)
                listening_s.append(time.perf_counter() - started)
                page.goto(f"http://127.0.0.1:{port}/")
                while not _drawn(page, camera, centre, rgb, folder / "shot.png"):
                    assert time.perf_counter() - started < 60.0, "the viewer did not draw the arm within 60 s"
                open_s.append(time.perf_counter() - started)
            finally:
                process.terminate()
                process.wait(timeout=30)
                page.close()
            started = time.perf_counter()
            subprocess.run(
                [sys.executable, "-m", "hydroarm.cli", "view", str(run_file), "--out", str(html)],
                check=True,
                stdout=subprocess.DEVNULL,
            )
            html_s.append(time.perf_counter() - started)
        browser.close()
    return {
        "steps": len(traj.t),
        "open_to_drawn_s": {"median": float(np.median(open_s)), "all": open_s},
        "open_to_listening_s": {"median": float(np.median(listening_s)), "all": listening_s},
        "write_html_s": {"median": float(np.median(html_s)), "all": html_s},
        "html_bytes": html.stat().st_size,
        "npz_bytes": run_file.stat().st_size,
    }


def render_viewer(section: dict) -> str:
    """The viewer's section of bench.md."""
    if "skipped" in section:
        return f"\n## Browser viewer\n\nSkipped: {section['skipped']}\n"
    return (
        "\n## Browser viewer\n\n"
        f"A {section['steps']}-step run (10 s): `hydroarm view` to the arm drawn in headless Chromium "
        f"{section['open_to_drawn_s']['median']:.2f} s (median; the server listening after "
        f"{section.get('open_to_listening_s', {}).get('median', float('nan')):.2f} s, then the page is "
        "opened); the shareable `.html` written in "
        f"{section['write_html_s']['median']:.2f} s, {section['html_bytes'] / 1e6:.2f} MB "
        f"(the run's `.npz`: {section['npz_bytes'] / 1e6:.2f} MB).\n"
    )
