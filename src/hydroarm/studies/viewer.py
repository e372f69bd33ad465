"""See a run in the browser: the arm in 3-D with its reference ghosted, a time slider, the time series.

Built on viser (the ``viewer`` extra; ``docs/viewer.md`` says why viser and not Rerun or
MeshCat): a local web server whose page (three.js, bundled in the wheel, nothing fetched
from the internet) shows

* every wetted cylinder of the arm at its true diameter (thin ones widened to stay
  visible), following the true joint angles ``q``, coloured by link as
  :mod:`hydroarm.studies.animate` colours them; the reference pose ``q_r`` as a grey,
  transparent ghost;
* on a vehicle-manipulator run (``meta["vehicle"]`` and ``extra["base_pose"]``, as
  :mod:`~hydroarm.studies.animate` draws it), the vehicle's hull box following the base pose
  with the arm on its mount, and the station-keeping target's axes; the camera looks at the
  target, so the drift shows;
* a time slider and a play/pause button (real time; a speed setting);
* the time series a user compares (:mod:`hydroarm.studies.viewer_charts`, inline SVG drawn at
  their real width in the first frame): the joint errors ``q_r - q``, the torque of one joint
  against its limit, the true disturbance against the controller's estimate with its +-2 sigma
  band (the joint is chosen in a dropdown), and on a vehicle run the base's drift and attitude;
  a time cursor on every chart follows the slider and playback.

:func:`write_html` writes the shareable recording: one self-contained ``.html`` (viser's
client and the recorded scene, played back with its own timeline and play button) with the
same charts in a side panel, their cursor following the recording's playback and scrubbing.

    from hydroarm.studies.viewer import TrajectoryViewer, write_html
    viewer = TrajectoryViewer("run.npz", port=8080)   # http://127.0.0.1:8080
    write_html("run.npz", "run.html")
"""

from __future__ import annotations

import html
import math
import threading
import time
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import numpy as np
import viser
import viser.transforms

from hydroarm.model.arm.description import Arm
from hydroarm.sim.runner import Trajectory
from hydroarm.studies.playback import VehicleMotion, as_arm, as_trajectory, reach, vehicle_motion
from hydroarm.studies.viewer_charts import LINK_RGB, PLOT_WIDTH, RunCharts, cursor_style

BASE_RGB = (105, 105, 105)
GHOST_RGB = (150, 150, 150)
GHOST_OPACITY = 0.3
HULL_RGB, HULL_OPACITY = (255, 199, 13), 0.45  # animate.HULL_COLOUR: translucent amber, no link's colour
ELEVATION, AZIMUTH = math.radians(22.0), math.radians(-55.0)  # as animate's camera
FOV = math.radians(50.0)  # vertical field of view of the camera


@dataclass(frozen=True)
class Camera:
    """A three.js perspective camera: ``position`` and ``look_at`` (m, world), vertical ``fov`` (rad), +z up."""

    position: np.ndarray
    look_at: np.ndarray
    fov: float = FOV

    def project(self, points: np.ndarray, width: float, height: float) -> np.ndarray:
        """Pixel coordinates (x right, y down) of world ``points`` (..., 3) on a ``width`` x ``height`` canvas."""
        forward = self.look_at - self.position
        forward = forward / np.linalg.norm(forward)
        right = np.cross(forward, np.array([0.0, 0.0, 1.0]))
        right = right / np.linalg.norm(right)
        up = np.cross(right, forward)
        rel = np.asarray(points, dtype=float) - self.position
        depth = rel @ forward
        scale = 1.0 / math.tan(self.fov / 2.0)
        ndc_x = scale * (rel @ right) / depth / (width / height)
        ndc_y = scale * (rel @ up) / depth
        return np.stack([(ndc_x + 1.0) / 2.0 * width, (1.0 - ndc_y) / 2.0 * height], axis=-1)


def camera_for(extent: float, centre: np.ndarray | None = None) -> Camera:
    """The fixed camera that frames a sphere of radius ``extent`` (m) round ``centre`` (3,) m (default:
    the base), seen as animate sees it."""
    direction = np.array(
        [math.cos(ELEVATION) * math.cos(AZIMUTH), math.cos(ELEVATION) * math.sin(AZIMUTH), math.sin(ELEVATION)]
    )
    distance = 0.9 * extent / math.sin(FOV / 2.0)
    look_at = np.zeros(3) if centre is None else np.asarray(centre, dtype=float)
    return Camera(position=look_at + distance * direction, look_at=look_at)


def cylinder_poses(arm: Arm, q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Midpoints (C, 3), orientations ``wxyz`` (C, 4) taking +z to each axis and lengths (C,) of the cylinders."""
    ends = arm.cylinder_endpoints(q)
    axis = ends[:, 1] - ends[:, 0]
    length = np.linalg.norm(axis, axis=1)
    unit = axis / np.where(length > 0.0, length, 1.0)[:, None]
    unit[length <= 0.0] = (0.0, 0.0, 1.0)
    # the shortest rotation from +z to unit: q = (1 + z.u, z x u), normalised
    w = 1.0 + unit[:, 2]
    xyz = np.stack([-unit[:, 1], unit[:, 0], np.zeros(len(unit))], axis=1)
    wxyz = np.column_stack([w, xyz])
    flipped = w < 1e-9  # unit = -z: half a turn about x
    wxyz[flipped] = (0.0, 1.0, 0.0, 0.0)
    wxyz /= np.linalg.norm(wxyz, axis=1, keepdims=True)
    return 0.5 * (ends[:, 0] + ends[:, 1]), wxyz, length


def link_colour(arm: Arm, index: int) -> tuple[int, int, int]:
    """The RGB colour (0-255) of cylinder ``index``: its link's tab10 colour, the base grey."""
    joint = arm.cylinders[index].joint_id
    return LINK_RGB[(joint - 1) % len(LINK_RGB)] if joint > 0 else BASE_RGB


class ArmScene:
    """The arm's cylinders (solid, following ``q``) and their ghost (following ``q_r``) in a viser scene.

    With a ``vehicle``: under ``/vehicle`` (placed at the base pose) its hull box
    (``/vehicle/hull``) and the mount frame carrying the arm; the camera and the floor grid are
    centred on the station-keeping target, whose axes are drawn (``/target``).
    """

    def __init__(self, server: viser.ViserServer, arm: Arm, extent: float, vehicle: VehicleMotion | None = None):
        self.arm = arm
        self.camera = camera_for(extent, None if vehicle is None else vehicle.target)
        scene = server.scene
        scene.set_up_direction("+z")
        # plain lights, no shadows, no HDR environment map: a software-rendered (no GPU) browser
        # draws the first frame several times faster (bench: docs/bench.md, "Browser viewer")
        scene.configure_environment_map(hdri=None)
        scene.configure_default_lights(enabled=True, cast_shadow=False)
        server.initial_camera.position = tuple(self.camera.position)
        server.initial_camera.look_at = tuple(self.camera.look_at)
        server.initial_camera.fov = self.camera.fov
        self.base = self.hull = None
        root = ""
        if vehicle is None:
            scene.add_grid("/floor", width=2.0 * extent, height=2.0 * extent, cell_size=extent / 5.0)
        else:
            floor = vehicle.target - (0.0, 0.0, extent / 2.0)  # below the vehicle, centred on the target
            scene.add_grid("/floor", width=2.0 * extent, height=2.0 * extent, cell_size=extent / 5.0, position=floor)
            scene.add_frame("/target", axes_length=0.1 * extent, axes_radius=0.004 * extent, position=vehicle.target)
            self.base = scene.add_frame("/vehicle", show_axes=False)
            self.hull = scene.add_box(
                "/vehicle/hull", color=HULL_RGB, dimensions=tuple(2.0 * vehicle.half), opacity=HULL_OPACITY
            )
            mount = viser.transforms.SO3.from_matrix(vehicle.mount_rotation).wxyz
            scene.add_frame(
                "/vehicle/mount", show_axes=False, wxyz=tuple(mount), position=tuple(vehicle.mount_translation)
            )
            root = "/vehicle/mount"
        thinnest = 0.012 * extent
        radii = [max(c.diameter / 2.0, thinnest) for c in arm.cylinders]
        _, _, lengths = cylinder_poses(arm, np.zeros(arm.n_joints))
        self.solid, self.ghost = [], []
        for index, (radius, length) in enumerate(zip(radii, lengths)):
            self.ghost.append(
                scene.add_cylinder(
                    f"{root}/reference/cylinder_{index}",
                    radius=radius * 1.02,
                    height=max(float(length), 1e-6),
                    color=GHOST_RGB,
                    opacity=GHOST_OPACITY,
                    radial_segments=24,
                )
            )
            self.solid.append(
                scene.add_cylinder(
                    f"{root}/arm/cylinder_{index}",
                    radius=radius,
                    height=max(float(length), 1e-6),
                    color=link_colour(arm, index),
                    radial_segments=24,
                )
            )

    def show(self, q: np.ndarray, q_ref: np.ndarray, pose: np.ndarray | None = None) -> None:
        """Move the arm to ``q`` and the ghost to ``q_ref``; on a vehicle, the base to ``pose``
        (7,: position m, quaternion x y z w)."""
        if self.base is not None and pose is not None:
            self.base.position = tuple(pose[:3])
            self.base.wxyz = (pose[6], pose[3], pose[4], pose[5])
        for handles, angles in ((self.solid, q), (self.ghost, q_ref)):
            centres, wxyz, _ = cylinder_poses(self.arm, angles)
            for handle, centre, rotation in zip(handles, centres, wxyz):
                handle.position = tuple(centre)
                handle.wxyz = tuple(rotation)


def scene_extent(traj: Trajectory, arm: Arm, vehicle: VehicleMotion | None) -> float:
    """Half width (m) of the view: the arm's reach, or on a vehicle the drift and the body (animate's)."""
    configurations = np.concatenate([traj.q, traj.q_ref])
    if vehicle is None:
        return reach(arm, configurations)
    return vehicle.extent(arm, np.arange(len(traj.t)), configurations)


def _title(arm: Arm, traj: Trajectory, vehicle: VehicleMotion | None) -> str:
    name = arm.name if vehicle is None else f"{vehicle.name} + {arm.name}"
    return f"{name}: {traj.meta.get('controller', '')}, {len(traj.t)} steps"


def _clock(traj: Trajectory, vehicle: VehicleMotion | None, k: int) -> str:
    """The time of sample ``k`` and its tracking error (and the vehicle's drift), as text."""
    error = float(np.linalg.norm(traj.q_ref[k] - traj.q[k]))
    text = f"t = {traj.t[k]:.2f} s, |q_r - q| = {error:.3f} rad"
    if vehicle is not None:
        text += f", drift = {float(np.linalg.norm(vehicle.poses[k, :3] - vehicle.target)):.3f} m"
    return text


def _boxed(chart: str) -> str:
    """A chart inset in the control panel as viser insets its own elements (and framed as its plots are)."""
    return (
        '<div style="padding:0 0.75rem 0.625rem"><div style="border:1px solid #dee2e6;border-radius:4px;'
        f'padding:4px 2px">{chart}</div></div>'
    )


class TrajectoryViewer:
    """Serve ``trajectory`` (a :class:`Trajectory` or its ``.npz``) at ``http://host:port``.

    ``arm``: the run's arm (default: the trajectory's ``meta["arm"]``). The server runs in
    background threads until :meth:`stop`; ``url`` is the page's address. ``server``: an
    already-started viser server to fill (``host`` and ``port`` then only name it): a browser
    may load the page while the run and the arm are still loading; the scene follows.
    """

    def __init__(
        self,
        trajectory: Trajectory | str | Path,
        arm: Arm | str | Path | None = None,
        host: str = "127.0.0.1",
        port: int = 8080,
        verbose: bool = False,
        server: viser.ViserServer | None = None,
    ):
        self.traj = as_trajectory(trajectory)
        self.arm = as_arm(arm, self.traj)
        self.vehicle = vehicle_motion(self.traj)
        traj = self.traj
        if server is None:
            server = viser.ViserServer(host=host, port=port, label="hydroarm", verbose=verbose)
        self.server = server
        self.url = f"http://{host}:{self.server.get_port()}"
        gui = self.server.gui
        gui.configure_theme(control_width="large", show_share_button=False)
        gui.main_panel.dock_right()  # the controls and charts in a panel beside the scene
        self.scene = ArmScene(self.server, self.arm, scene_extent(traj, self.arm, self.vehicle), self.vehicle)
        gui.add_markdown(f"**{_title(self.arm, traj, self.vehicle)}**")
        period = float(traj.t[1] - traj.t[0]) if len(traj.t) > 1 else 0.01
        self.slider = gui.add_slider(
            "t (s)", min=float(traj.t[0]), max=float(traj.t[-1]), step=period, initial_value=float(traj.t[0])
        )
        self.play = gui.add_button("play / pause")
        self.speed = gui.add_slider("speed", min=0.1, max=4.0, step=0.1, initial_value=1.0)
        self.clock = gui.add_html("")
        self.playing = False
        self._lock = threading.Lock()
        self.slider.on_update(lambda _: self.show_time(self.slider.value))
        self.play.on_click(lambda _: self.toggle())
        self._charts()
        self.show_time(float(traj.t[0]))
        self._stop = threading.Event()
        self._player = threading.Thread(target=self._run_player, daemon=True)
        self._player.start()

    def _charts(self) -> None:
        gui = self.server.gui
        self.charts = RunCharts(self.traj, self.arm, self.vehicle)
        gui.add_html(_boxed(self.charts.errors()))
        if self.vehicle is not None:
            gui.add_html(_boxed(self.charts.drift()))
            gui.add_html(_boxed(self.charts.attitude()))
        self.joint = gui.add_dropdown(
            "joint", options=[str(j + 1) for j in range(self.arm.n_joints)], initial_value="1"
        )
        self.torque_plot = gui.add_html(_boxed(self.charts.torque(0)))
        self.disturbance_plot = gui.add_html(_boxed(self.charts.disturbance(0)))
        self.joint.on_update(lambda _: self._choose_joint(int(self.joint.value) - 1))

    def _choose_joint(self, j: int) -> None:
        with self.server.atomic():
            self.torque_plot.content = _boxed(self.charts.torque(j))
            self.disturbance_plot.content = _boxed(self.charts.disturbance(j))

    def index(self, time_s: float) -> int:
        """The sample nearest ``time_s`` (s)."""
        return int(np.argmin(np.abs(self.traj.t - time_s)))

    def show_time(self, time_s: float) -> None:
        """Draw the arm and its reference (and the vehicle) at the sample nearest ``time_s``, and
        move the charts' time cursor there."""
        k = self.index(time_s)
        traj = self.traj
        with self._lock, self.server.atomic():
            self.scene.show(traj.q[k], traj.q_ref[k], None if self.vehicle is None else self.vehicle.poses[k])
            offset = self.charts.chart.cursor_offset(float(traj.t[k]))
            clock = f'<div style="padding:0 0.75rem 0.625rem;font-size:0.875rem">{_clock(traj, self.vehicle, k)}</div>'
            self.clock.content = clock + cursor_style(offset)

    def toggle(self) -> None:
        """Play from the slider's time (from the start at the end), or pause."""
        if not self.playing and self.slider.value >= self.slider.max - 1e-9:
            self.slider.value = self.slider.min
        self.playing = not self.playing

    def _run_player(self, frame_period: float = 1.0 / 25.0) -> None:
        while not self._stop.wait(frame_period):
            if not self.playing:
                continue
            value = min(self.slider.value + self.speed.value * frame_period, self.slider.max)
            self.slider.value = value
            self.show_time(value)
            if value >= self.slider.max:
                self.playing = False

    def stop(self) -> None:
        """Stop the player and the server."""
        self._stop.set()
        self.server.stop()


def write_html(
    trajectory: Trajectory | str | Path,
    out_path: str | Path,
    arm: Arm | str | Path | None = None,
    fps: float = 25.0,
) -> Path:
    """Write a self-contained ``.html`` playing ``trajectory`` back (``fps`` frames a second, real time).

    Opens in any browser, offline, with no server: viser's client with the recorded scene
    (timeline, play/pause) and the run's charts in a side panel (:func:`recording_panel`),
    their time cursor following the playback; send it to a colleague. Returns the path.
    """
    import contextlib
    import io

    traj = as_trajectory(trajectory)
    the_arm = as_arm(arm, traj)
    vehicle = vehicle_motion(traj)
    quiet = contextlib.ExitStack()  # the server only serialises the scene: no banner for the user
    quiet.enter_context(contextlib.redirect_stdout(io.StringIO()))
    quiet.enter_context(contextlib.redirect_stderr(io.StringIO()))
    with quiet:
        server = viser.ViserServer(host="127.0.0.1", port=_free_port(), verbose=False)
    try:
        scene = ArmScene(server, the_arm, scene_extent(traj, the_arm, vehicle), vehicle)

        def show(k: int) -> None:
            scene.show(traj.q[k], traj.q_ref[k], None if vehicle is None else vehicle.poses[k])

        show(0)
        serializer = server.get_scene_serializer()
        period = float(traj.t[1] - traj.t[0]) if len(traj.t) > 1 else 1.0 / fps
        stride = max(1, int(round(1.0 / (fps * period))))
        for k in range(stride, len(traj.t), stride):
            serializer.insert_sleep(stride * period)
            show(k)
        page = serializer.as_html()
    finally:
        with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
            server.stop()
    page = page.replace(
        "<title>Viser</title>", f"<title>hydroarm: {html.escape(_title(the_arm, traj, vehicle))}</title>", 1
    )
    end = page.rindex("</body>")
    page = page[:end] + recording_panel(traj, the_arm, vehicle) + page[end:]
    out_path = Path(out_path)
    tmp = out_path.with_name(out_path.name + ".tmp")
    tmp.write_text(page)
    tmp.replace(out_path)
    return out_path


def recording_panel(traj: Trajectory, arm: Arm, vehicle: VehicleMotion | None = None) -> str:
    """The recording's side panel (HTML): its style, the run's title and clock, every chart (the
    torque and disturbance of every joint, one joint shown at a time) and the script moving the
    charts' cursor with viser's playback bar (``hydroarm/studies/viewer_web``)."""
    web = resources.files("hydroarm.studies") / "viewer_web"
    charts = RunCharts(traj, arm, vehicle)
    options = "".join(f"<option>{j + 1}</option>" for j in range(arm.n_joints))
    joints = "".join(
        f'<div data-joint="{j + 1}"{" hidden" if j else ""}>{charts.torque(j)}{charts.disturbance(j)}</div>'
        for j in range(arm.n_joints)
    )
    vehicle_charts = "" if vehicle is None else charts.drift() + charts.attitude()
    return (
        f"<style>{(web / 'recording.css').read_text()}</style>"
        f'<aside id="hydroarm-panel" data-start="{float(traj.t[0])!r}" data-span="{charts.chart.span!r}" '
        f'data-plot-width="{PLOT_WIDTH!r}">'
        f"<h1>{html.escape(_title(arm, traj, vehicle))}</h1>"
        f'<div id="hydroarm-clock">t = {float(traj.t[0]):.2f} s</div>'
        f"{charts.errors()}{vehicle_charts}"
        f'<label>joint <select id="hydroarm-joint">{options}</select></label>{joints}'
        "<p>Recorded by <code>hydroarm view --out</code>: the scene plays in real time below the timeline; "
        "the charts' cursor follows it.</p></aside>"
        f"<script>{(web / 'recording.js').read_text()}</script>"
    )


def _free_port() -> int:
    import socket

    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def serve_until_interrupted(viewer: TrajectoryViewer) -> None:
    """Block until Ctrl-C, then stop ``viewer``."""
    try:
        while True:
            time.sleep(0.5)
    except KeyboardInterrupt:
        pass
    finally:
        viewer.stop()
