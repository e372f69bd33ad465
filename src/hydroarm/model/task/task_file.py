"""Your own trajectory: a task from settings or a file, and where the run starts.

``TaskConfig`` (the ``task`` section of the experiment settings):

* ``kind = "arm"`` (default): the arm's own task (:func:`~hydroarm.model.task.references.task_for_arm`: the
  paper's sinusoids, scaled into the joint ranges);
* ``kind = "sinusoids"``: ``q_i(t) = offset_i + sum_m cos_amp[i][m] cos(omega[i][m] t) +
  sin_amp[i][m] sin(omega[i][m] t)`` (rad, rad/s) from the settings;
* ``kind = "file"``: ``file`` is a TOML file with the same four keys, or a CSV of samples
  ``t, q_1, ..., q_n`` (s, rad; a header line is allowed) interpolated by a cubic spline per joint
  (scipy's ``CubicSpline``, not-a-knot ends), which gives q, q' and q'' everywhere; outside the
  samples' span the reference holds its end values (time clamped). At least 4 samples,
  strictly increasing times, n joint columns, finite values.

``start``: ``"task"`` (default: the task's own start, at rest; the paper's) or
``"on_trajectory"``: the run starts at ``[q_r(0), q_r'(0)]``, with no initial error.
"""

from __future__ import annotations

import csv
import tomllib
from pathlib import Path
from typing import Annotated, Literal

import numpy as np
import pydantic
import scipy.interpolate

from hydroarm.config import ConfigError, FrozenModel
from hydroarm.model.arm.description import Arm
from hydroarm.model.task.references import SinusoidReference, task_for_arm

Amplitudes = list[list[Annotated[float, pydantic.Field(ge=-1e3, le=1e3)]]]
MIN_SAMPLES = 4


class TaskConfig(FrozenModel):
    """The reference the run tracks and where it starts (module docstring)."""

    kind: Literal["arm", "sinusoids", "file"] = pydantic.Field(
        "arm", description="arm: the arm's own task; sinusoids: the coefficients below; file: a TOML or CSV file"
    )
    file: str | None = pydantic.Field(None, description="kind = file: a .toml (sinusoids) or .csv (t, q_1..q_n) file")
    offset: list[Annotated[float, pydantic.Field(ge=-1e3, le=1e3)]] | None = pydantic.Field(
        None, description="kind = sinusoids: q offsets, one per joint (rad)"
    )
    cos_amp: Amplitudes | None = pydantic.Field(
        None, description="kind = sinusoids: cosine amplitudes, a list per joint (rad)"
    )
    sin_amp: Amplitudes | None = pydantic.Field(
        None, description="kind = sinusoids: sine amplitudes, a list per joint (rad)"
    )
    omega: Amplitudes | None = pydantic.Field(
        None, description="kind = sinusoids: frequencies, a list per joint (rad/s)"
    )
    start: Literal["task", "on_trajectory"] = pydantic.Field(
        "task", description="task: the task's own start (at rest); on_trajectory: at the reference, no initial error"
    )

    @pydantic.model_validator(mode="after")
    def _complete(self) -> TaskConfig:
        if self.kind == "file" and not self.file:
            raise ValueError("kind = 'file' needs task.file (a .toml or .csv file)")
        if self.kind == "sinusoids" and None in (self.offset, self.cos_amp, self.sin_amp, self.omega):
            raise ValueError("kind = 'sinusoids' needs task.offset, task.cos_amp, task.sin_amp and task.omega")
        return self


class SplineReference:
    """A reference through samples ``times`` (K,) s, ``q`` (K, n) rad: cubic splines per joint,
    with the time clamped to the samples' span. ``sample(t) -> (q, v, a)`` like
    :class:`~hydroarm.model.task.references.SinusoidReference`."""

    def __init__(self, times: np.ndarray, q: np.ndarray):
        self.times = np.asarray(times, dtype=float)
        self.q = np.asarray(q, dtype=float)
        self._spline = scipy.interpolate.CubicSpline(self.times, self.q, axis=0)
        self._velocity = self._spline.derivative(1)
        self._acceleration = self._spline.derivative(2)

    @property
    def n_joints(self) -> int:
        return int(self.q.shape[1])

    def sample(self, t: float | np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(q, v, a)`` at time(s) t (s): (n,) each for scalar t, else (len(t), n)."""
        clamped = np.clip(np.asarray(t, dtype=float), self.times[0], self.times[-1])
        return self._spline(clamped), self._velocity(clamped), self._acceleration(clamped)

    def state(self, t: float) -> np.ndarray:
        """``[q_r, v_r]`` (2n,) at time t (s)."""
        q, v, _ = self.sample(t)
        return np.concatenate([q, v])


def _sinusoids(offset, cos_amp, sin_amp, omega, n: int, source: str) -> SinusoidReference:
    arrays = {"offset": offset, "cos_amp": cos_amp, "sin_amp": sin_amp, "omega": omega}
    try:
        values = {key: np.asarray(value, dtype=float) for key, value in arrays.items()}
    except (TypeError, ValueError):
        raise ConfigError(f"{source}: offset, cos_amp, sin_amp and omega must be numbers (lists per joint)") from None
    if values["offset"].shape != (n,):
        raise ConfigError(f"{source}: offset has {values['offset'].size} values: give one per joint ({n})")
    shape = values["omega"].shape
    for key in ("cos_amp", "sin_amp", "omega"):
        if values[key].ndim != 2 or values[key].shape[0] != n:
            raise ConfigError(f"{source}: {key} must be {n} rows (one per joint) of equally many terms")
        if values[key].shape != shape:
            raise ConfigError(
                f"{source}: cos_amp, sin_amp and omega must have the same shape, {key} is {values[key].shape}"
            )
    if not all(np.all(np.isfinite(v)) for v in values.values()):
        raise ConfigError(f"{source}: every coefficient must be finite")
    return SinusoidReference(values["offset"], values["cos_amp"], values["sin_amp"], values["omega"])


def read_csv_task(path: Path, n: int) -> SplineReference:
    """The spline reference of a CSV file of rows ``t, q_1..q_n`` (module docstring); raises
    :class:`ConfigError` naming the line and what is wrong."""
    try:
        lines = path.read_text().splitlines()
    except OSError as error:
        raise ConfigError(f"task.file '{path}': cannot be read ({error.strerror})") from None
    rows: list[list[float]] = []
    for number, row in enumerate(csv.reader(lines), start=1):
        if not row or all(not cell.strip() for cell in row):
            continue
        try:
            values = [float(cell) for cell in row]
        except ValueError:
            if not rows and number == 1:
                continue  # a header
            raise ConfigError(f"task.file '{path}', line {number}: not numbers: {','.join(row)[:60]!r}") from None
        if len(values) != n + 1:
            raise ConfigError(
                f"task.file '{path}', line {number}: {len(values)} columns: give t and one q per joint ({n + 1})"
            )
        if not all(np.isfinite(values)):
            raise ConfigError(f"task.file '{path}', line {number}: values must be finite")
        rows.append(values)
    if len(rows) < MIN_SAMPLES:
        raise ConfigError(f"task.file '{path}': {len(rows)} samples: a spline needs at least {MIN_SAMPLES}")
    data = np.asarray(rows)
    steps = np.diff(data[:, 0])
    if np.any(steps <= 0.0):
        bad = int(np.flatnonzero(steps <= 0.0)[0]) + 2
        raise ConfigError(f"task.file '{path}': times must increase strictly (sample {bad} does not)")
    return SplineReference(data[:, 0] - data[0, 0], data[:, 1:])


def reference_for(task: TaskConfig, arm: Arm) -> tuple[SinusoidReference | SplineReference, np.ndarray]:
    """The reference and the start state (2n,) of ``task`` on ``arm`` (module docstring)."""
    n = arm.n_joints
    if task.kind == "arm":
        reference, x0 = task_for_arm(arm)
    elif task.kind == "sinusoids":
        reference = _sinusoids(task.offset, task.cos_amp, task.sin_amp, task.omega, n, "task")
        x0 = np.concatenate([reference.sample(0.0)[0], np.zeros(n)])
    else:
        path = Path(task.file)
        if not path.is_file():
            raise ConfigError(f"task.file '{path}': no such file")
        if path.suffix.lower() == ".csv":
            reference = read_csv_task(path, n)
        elif path.suffix.lower() == ".toml":
            try:
                data = tomllib.loads(path.read_text())
            except (OSError, tomllib.TOMLDecodeError) as error:
                raise ConfigError(f"task.file '{path}': not a readable TOML file ({error})") from None
            missing = [key for key in ("offset", "cos_amp", "sin_amp", "omega") if key not in data]
            if missing:
                raise ConfigError(f"task.file '{path}': missing {', '.join(missing)} (sinusoid coefficients)")
            reference = _sinusoids(data["offset"], data["cos_amp"], data["sin_amp"], data["omega"], n,
                                   f"task.file '{path}'")  # fmt: skip
        else:
            raise ConfigError(f"task.file '{path}': must end in .csv (t, q samples) or .toml (sinusoids)")
        x0 = np.concatenate([reference.sample(0.0)[0], np.zeros(n)])
    if task.start == "on_trajectory":
        x0 = reference.state(0.0)
    return reference, x0
