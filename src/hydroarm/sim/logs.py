"""Logs of a real vehicle + arm: the tank trials' CSV layout in, checked and cleaned.

A trial (:class:`TrialLog`) is three time series on one clock (s):

* the joints: ``joint_time`` (m,), ``joint_position`` (m, n) rad, named ``joint_names``;
* the IMU: ``imu_time`` (k,), ``imu_quaternion`` (k, 4: x y z w, vehicle to world);
* the motion capture (optional): ``mocap_time`` (p,), ``mocap_quaternion`` (p, 4).

The CSV layout (the Hinsdale 2023 dataset's, one file per stream beside each other):
``<trial>_joint_states.csv`` with ``time_secs`` and ``<joint>_pos`` (and ``<joint>_vel``)
columns, ``<trial>_imu.csv`` with ``time_secs, x_ori, y_ori, z_ori, w_ori`` (and the angular
velocity ``x_angvel..``), ``<trial>_mocap.csv`` with ``time_secs, x_ori..w_ori``. ROS 2 bags
(:mod:`hydroarm.sim.rosbag`) give the same :class:`TrialLog`; :mod:`hydroarm.sim.trials` reads
either.

Cleaning (:class:`CleaningConfig`, settings with defaults): the joints' republished readings
(the same value repeated until the next reading) are reduced to the readings themselves; a
one-sample glitch (a sample farther than ``outlier_threshold`` from the median of its
neighbours) is dropped; a smoothing spline per joint (``scipy.interpolate.make_smoothing_spline``,
penalty ``smoothing``) gives q, q' and q'' at any time. The attitude streams are cleaned of
spikes the same way (on roll and pitch).

Bad logs raise :class:`LogError` (a :class:`~hydroarm.config.ConfigError`: one line naming the
file, the column or the stream, and what is allowed; the CLI exits with code 2).
"""

from __future__ import annotations

import copy
import csv
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pinocchio as pin
import pydantic
from scipy.interpolate import BSpline, make_smoothing_spline

from hydroarm.config import ConfigError, FrozenModel

MIN_DURATION = 1.0
"""s: the shortest log a replay accepts."""
QUATERNION_COLUMNS = ("x_ori", "y_ori", "z_ori", "w_ori")
ANGULAR_VELOCITY_COLUMNS = ("x_angvel", "y_angvel", "z_angvel")


class LogError(ConfigError):
    """A log that cannot be replayed: the message names the file, the column and what is allowed."""


class CleaningConfig(FrozenModel):
    """How logs are cleaned before they are replayed (module docstring)."""

    drop_repeats: bool = pydantic.Field(True, description="keep only the readings of republished joint values (on/off)")
    repeat_hold: float = pydantic.Field(
        0.2,
        gt=0.0,
        le=10.0,
        description="s: a value repeated longer than this is a joint at rest: its last repeat is kept too",
    )
    outlier_window: int = pydantic.Field(
        5, ge=3, le=51, description="samples in the median window of the glitch filter (odd)"
    )
    outlier_threshold: float = pydantic.Field(
        0.02, gt=0.0, le=10.0, description="rad: a sample farther than this from its neighbours' median is dropped"
    )
    smoothing: float | None = pydantic.Field(
        1e-2,
        gt=0.0,
        le=1e6,
        description="penalty lambda of the joints' smoothing spline (s^3 scale; None: generalised cross-validation)",
    )


@dataclass(frozen=True)
class TrialLog:
    """One trial's streams (module docstring); times in s, angles in rad."""

    name: str
    joint_names: tuple[str, ...]
    joint_time: np.ndarray
    joint_position: np.ndarray
    imu_time: np.ndarray
    imu_quaternion: np.ndarray
    imu_angular_velocity: np.ndarray | None = None
    mocap_time: np.ndarray | None = None
    mocap_quaternion: np.ndarray | None = None
    source: str = ""

    @property
    def n_joints(self) -> int:
        return len(self.joint_names)

    def select_joints(self, names: tuple[str, ...] | list[str]) -> TrialLog:
        """The same log with only the joints ``names``, in that order (a missing one: LogError)."""
        index = []
        for name in names:
            if name not in self.joint_names:
                raise LogError(
                    f"{self.source or self.name}: no joint {name!r} in the log "
                    f"(it has {', '.join(self.joint_names)}): the arm's joints must be logged by name"
                )
            index.append(self.joint_names.index(name))
        return TrialLog(
            name=self.name,
            joint_names=tuple(names),
            joint_time=self.joint_time,
            joint_position=self.joint_position[:, index],
            imu_time=self.imu_time,
            imu_quaternion=self.imu_quaternion,
            imu_angular_velocity=self.imu_angular_velocity,
            mocap_time=self.mocap_time,
            mocap_quaternion=self.mocap_quaternion,
            source=self.source,
        )


# --- reading ------------------------------------------------------------------------


def _read_csv(path: Path, required: tuple[str, ...]) -> dict[str, np.ndarray]:
    if not path.is_file():
        raise LogError(f"{path}: no such file")
    with path.open(newline="") as handle:
        reader = csv.reader(handle)
        try:
            header = [name.strip() for name in next(reader)]
        except StopIteration:
            raise LogError(f"{path}: empty file (expected a header with {', '.join(required)})") from None
        rows = list(reader)
    missing = [name for name in required if name not in header]
    if missing:
        raise LogError(f"{path}: missing column(s) {', '.join(missing)} (the header has {', '.join(header)})")
    try:
        table = np.array([[float(x) for x in row] for row in rows if row], dtype=float)
    except ValueError as error:
        raise LogError(f"{path}: a value is not a number ({error})") from None
    if table.ndim != 2 or table.shape[0] == 0:
        raise LogError(f"{path}: no data rows")
    if table.shape[1] != len(header):
        raise LogError(f"{path}: rows of {table.shape[1]} values under a header of {len(header)} columns")
    return {name: table[:, i] for i, name in enumerate(header)}


def _check_stream(path: str, column: str, time: np.ndarray, values: np.ndarray) -> None:
    bad = ~np.isfinite(values)
    if bad.any():
        row = int(np.argwhere(bad)[0][0])
        raise LogError(f"{path}: column {column} is NaN or infinite at row {row + 1} (t = {time[row]!r} s)")
    _check_time(path, time)


def _check_time(path: str, time: np.ndarray) -> None:
    if not np.all(np.isfinite(time)):
        raise LogError(f"{path}: time_secs has NaN or infinite values")
    steps = np.diff(time)
    if np.any(steps == 0.0):
        row = int(np.argwhere(steps == 0.0)[0][0])
        raise LogError(f"{path}: duplicated time stamp {time[row]!r} s at rows {row + 1}, {row + 2}")
    if np.any(steps < 0.0):
        row = int(np.argwhere(steps < 0.0)[0][0])
        raise LogError(
            f"{path}: time stamps go back at row {row + 2} ({time[row]!r} -> {time[row + 1]!r} s): "
            "time_secs must increase"
        )
    if time[-1] - time[0] < MIN_DURATION:
        raise LogError(f"{path}: {time[-1] - time[0]:.3f} s long: a log must cover at least {MIN_DURATION:g} s")


def trial_prefix(path: str | Path) -> tuple[Path, str]:
    """``(folder, trial name)`` of a ``<trial>_joint_states.csv`` path (or the prefix itself)."""
    path = Path(path)
    name = path.name
    for suffix in ("_joint_states.csv", "_imu.csv", "_mocap.csv"):
        if name.endswith(suffix):
            return path.parent, name[: -len(suffix)]
    return path.parent, name


def load_csv_trial(path: str | Path, joint_names: tuple[str, ...] | None = None) -> TrialLog:
    """A trial from its CSV files (``<trial>_joint_states.csv`` and its ``_imu`` / ``_mocap``
    siblings). ``joint_names``: the joints to read (default: every ``<name>_pos`` column)."""
    folder, name = trial_prefix(path)
    joints_path = folder / f"{name}_joint_states.csv"
    if not joints_path.is_file():
        raise LogError(f"{joints_path}: no such file (a trial is <trial>_joint_states.csv, _imu.csv, _mocap.csv)")
    joints = _read_csv(joints_path, ("time_secs",))
    logged = tuple(c[: -len("_pos")] for c in joints if c.endswith("_pos"))
    if not logged:
        raise LogError(f"{joints_path}: no <joint>_pos column (the header has {', '.join(joints)})")
    names = joint_names or logged
    missing = [n for n in names if n not in logged]
    if missing:
        raise LogError(
            f"{joints_path}: {len(logged)} joints logged ({', '.join(logged)}) but the arm has {len(names)} "
            f"({', '.join(names)}): no column {', '.join(m + '_pos' for m in missing)}"
        )
    joints = _read_csv(joints_path, ("time_secs", *(f"{n}_pos" for n in names)))
    time = joints["time_secs"]
    position = np.column_stack([joints[f"{n}_pos"] for n in names])
    for n in names:
        _check_stream(str(joints_path), f"{n}_pos", time, joints[f"{n}_pos"])
    imu_path = folder / f"{name}_imu.csv"
    imu = _read_csv(imu_path, ("time_secs", *QUATERNION_COLUMNS))
    quaternion = np.column_stack([imu[c] for c in QUATERNION_COLUMNS])
    for c in QUATERNION_COLUMNS:
        _check_stream(str(imu_path), c, imu["time_secs"], imu[c])
    rates = None
    if all(c in imu for c in ANGULAR_VELOCITY_COLUMNS):
        rates = np.column_stack([imu[c] for c in ANGULAR_VELOCITY_COLUMNS])
    mocap_time = mocap_quaternion = None
    mocap_path = folder / f"{name}_mocap.csv"
    if mocap_path.is_file():
        mocap = _read_csv(mocap_path, ("time_secs", *QUATERNION_COLUMNS))
        finite = np.all(np.isfinite(np.column_stack([mocap[c] for c in QUATERNION_COLUMNS])), axis=1)
        mocap_time = mocap["time_secs"][finite]  # dropouts are gaps, not errors
        mocap_quaternion = np.column_stack([mocap[c][finite] for c in QUATERNION_COLUMNS])
        _check_time(str(mocap_path), mocap_time)
    return TrialLog(
        name=name,
        joint_names=tuple(names),
        joint_time=time,
        joint_position=position,
        imu_time=imu["time_secs"],
        imu_quaternion=quaternion,
        imu_angular_velocity=rates,
        mocap_time=mocap_time,
        mocap_quaternion=mocap_quaternion,
        source=str(joints_path),
    )


# --- cleaning -----------------------------------------------------------------------


def drop_repeats(time: np.ndarray, values: np.ndarray, hold: float) -> np.ndarray:
    """Mask (m,) of the samples of one joint that are readings: the first of every run of equal
    values, and a run's last sample too when the run lasts longer than ``hold`` s (at rest)."""
    keep = np.ones(time.size, dtype=bool)
    same = values[1:] == values[:-1]
    keep[1:] = ~same
    start = 0
    for i in range(1, time.size + 1):
        if i == time.size or not same[i - 1]:
            if i - 1 > start and time[i - 1] - time[start] > hold:
                keep[i - 1] = True
            start = i
    return keep


def glitches(values: np.ndarray, window: int, threshold: float) -> np.ndarray:
    """Mask of one-sample glitches: farther than ``threshold`` from the running median of ``window``."""
    half = window // 2
    padded = np.pad(values, half, mode="edge")
    windows = np.lib.stride_tricks.sliding_window_view(padded, 2 * half + 1)
    return np.abs(values - np.median(windows, axis=1)) > threshold


class JointSplines:
    """The cleaned joint motion: ``sample(t) -> (q, v, a)`` (rad, rad/s, rad/s^2; (n,) each) from a
    smoothing spline per joint; held constant (zero rates) outside the logged span."""

    vectorised = True

    def __init__(self, splines: list[BSpline], span: tuple[float, float], delay: float = 0.0):
        self.splines = splines
        self.derivatives = [s.derivative(1) for s in splines]
        self.second = [s.derivative(2) for s in splines]
        self.span = span
        self.delay = delay

    def delayed(self, delay: float) -> JointSplines:
        """The same motion ``delay`` seconds later: ``sample(t)`` is this one's at ``t - delay``
        (a clock offset between the joints' log and the IMU's)."""
        out = copy.copy(self)  # the splines are shared, not refitted
        out.delay = self.delay + float(delay)
        return out

    def sample(self, t):
        t = np.asarray(t, dtype=float) - self.delay
        inside = (t >= self.span[0]) & (t <= self.span[1])
        clipped = np.clip(t, *self.span)
        q = np.stack([s(clipped) for s in self.splines], axis=-1)
        v = np.stack([d(clipped) for d in self.derivatives], axis=-1)
        a = np.stack([d(clipped) for d in self.second], axis=-1)
        mask = inside[..., None] if t.ndim else inside
        return q, np.where(mask, v, 0.0), np.where(mask, a, 0.0)

    def tabulate(self, start: float, step: float, count: int) -> GridMotion:
        """The same motion sampled once at ``start + k step`` (k < count): a fast ``sample``."""
        return GridMotion(self, start, step, *self.sample(start + step * np.arange(count)))


class GridMotion:
    """A motion tabulated on a uniform grid (:meth:`JointSplines.tabulate`); ``sample`` at a grid
    time is a lookup, elsewhere the splines'."""

    def __init__(self, motion: JointSplines, start: float, step: float, q, v, a):
        self.motion, self.start, self.step = motion, start, step
        self.q, self.v, self.a = q, v, a

    def sample(self, t: float):
        k = round((t - self.start) / self.step)
        if 0 <= k < self.q.shape[0] and abs(t - self.start - k * self.step) <= 1e-6 * self.step:
            return self.q[k], self.v[k], self.a[k]
        return self.motion.sample(t)


def joint_motion(log: TrialLog, config: CleaningConfig | None = None) -> JointSplines:
    """The cleaned, smoothed joint motion of a log (module docstring)."""
    config = config or CleaningConfig()
    time = log.joint_time
    splines = []
    for j, name in enumerate(log.joint_names):
        values = log.joint_position[:, j]
        keep = drop_repeats(time, values, config.repeat_hold) if config.drop_repeats else np.ones(time.size, bool)
        if keep.sum() < 5:  # a joint that hardly moves (held still): its every sample is a reading
            keep = np.ones(time.size, bool)
        t, y = time[keep], values[keep]
        bad = glitches(y, config.outlier_window, config.outlier_threshold)
        t, y = t[~bad], y[~bad]
        if t.size < 5:
            raise LogError(f"{log.source or log.name}: joint {name}: {t.size} readings after cleaning (need 5)")
        splines.append(make_smoothing_spline(t, y, lam=config.smoothing))
    return JointSplines(splines, (float(time[0]), float(time[-1])))


def roll_pitch_yaw(quaternion: np.ndarray) -> np.ndarray:
    """(k, 3) roll, pitch, yaw (rad; R = Rz(yaw) Ry(pitch) Rx(roll)) of (k, 4) quaternions x y z w."""
    out = np.empty((quaternion.shape[0], 3))
    for i, (x, y, z, w) in enumerate(quaternion):
        out[i] = pin.rpy.matrixToRpy(pin.Quaternion(w, x, y, z).normalized().toRotationMatrix())
    return out


def clean_attitude(time: np.ndarray, rpy: np.ndarray, config: CleaningConfig | None = None):
    """``(time, rpy)`` without the spikes of roll or pitch (the glitch filter of the joints)."""
    config = config or CleaningConfig()
    bad = glitches(rpy[:, 0], config.outlier_window, config.outlier_threshold) | glitches(
        rpy[:, 1], config.outlier_window, config.outlier_threshold
    )
    return time[~bad], rpy[~bad]
