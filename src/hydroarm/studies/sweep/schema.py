"""The sweep file: :class:`SweepConfig` and what it is made of, validated before any run.

A sweep file (TOML or YAML) names the controllers, the seeds, the settings shared by every
run (``[base]``, an :class:`~hydroarm.sim.experiment.ExperimentConfig`), the settings
that vary (``[parameters]``: a dotted key -> a list of values or a :class:`Range`), the
plant's rigid-body :class:`Mismatch`, the summary's ``metric`` (:data:`METRICS`) and its
tracking bound (:class:`Robustness`). See the package docstring for an example.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path
from typing import Annotated, Any, Literal, Self

import numpy as np
import pydantic

from hydroarm.config import ConfigError, FrozenModel, read_mapping, validate
from hydroarm.control.registry import canonical_name, controller_names
from hydroarm.sim.experiment import ExperimentConfig
from hydroarm.sim.mismatch import Mismatch
from hydroarm.sim.settings_schema import migrated

MAX_RUNS = 100_000
MISMATCH_PREFIX = "mismatch."


class Robustness(FrozenModel):
    """The tracking bound of the summary's robustness table.

    A run stays within the bound if it ran to the end (not diverged, not stopped
    by the runner) and from ``after`` s on |q_r - q| < ``max_error`` rad on every
    joint at every control step (true q). It is checked on the run's error
    envelope (the largest error over joints per
    :data:`~hydroarm.studies.sweep.worker.ENVELOPE_WINDOW` s), so
    ``after`` is rounded up to a window start. A run that ends before ``after``
    is never within the bound.
    """

    max_error: float = pydantic.Field(0.5, gt=0.0, le=100.0, description="rad")
    after: float = pydantic.Field(2.0, ge=0.0, le=3600.0, description="s")


class Range(FrozenModel):
    """A range of values: ``num`` evenly spaced points (grid) or uniform draws (random).

    ``log``: evenly spaced / uniform in log space (``low`` > 0); ``integer``:
    round to integers (e.g. ``gp.window``, ``mpc.horizon``).
    """

    low: float
    high: float
    log: bool = False
    integer: bool = False
    num: int | None = pydantic.Field(None, ge=1, le=10_000, description="grid mode: how many values")

    @pydantic.model_validator(mode="after")
    def _check(self) -> Self:
        if self.high < self.low:
            raise ValueError(f"high ({self.high}) < low ({self.low}): high must be at least low")
        if self.log and self.low <= 0.0:
            raise ValueError(f"log = true needs low > 0 (low = {self.low})")
        return self

    def grid(self) -> list[float | int]:
        """The ``num`` grid values (duplicates removed after integer rounding)."""
        num = int(self.num or 1)
        values = np.geomspace(self.low, self.high, num) if self.log else np.linspace(self.low, self.high, num)
        return unique([_as_number(x, self.integer) for x in values])

    def draw(self, rng: np.random.Generator) -> float | int:
        """One uniform draw (in log space if ``log``)."""
        if self.log:
            x = math.exp(rng.uniform(math.log(self.low), math.log(self.high)))
        else:
            x = rng.uniform(self.low, self.high)
        return _as_number(min(max(x, self.low), self.high), self.integer)


def _as_number(x: float, integer: bool) -> float | int:
    return int(round(float(x))) if integer else float(x)


def unique(values: list) -> list:
    """``values`` without repeats, in order (values need not be hashable)."""
    out: list = []
    for value in values:
        if value not in out:
            out.append(value)
    return out


METRICS = {
    "Ep_mean": ("mean E_p over joints", "rad$^2$"),
    "Ep_steady_mean": ("mean E_p over joints after 2 s", "rad$^2$"),
    "rms_mean": ("mean RMS error over joints", "rad"),
    "max_error": ("largest |error|", "rad"),
    "torque_rms_mean": ("mean RMS torque over joints", "N m"),
    "time_to_band_max": ("time to stay within 0.05 rad, slowest joint", "s"),
    "step_ms_median": ("median controller step", "ms"),
}
"""The columns a summary can compare (``metric`` in the sweep file): label, unit."""


def _registered(name: str) -> str:
    """The registry's canonical name of a controller (any spelling: ``gp-mpc``, ``GP_MPC``)."""
    try:
        return canonical_name(name)
    except ConfigError:
        raise ValueError(f"not a controller: give one of {', '.join(controller_names())} (any case; _ or -)") from None


ControllerName = Annotated[str, pydantic.AfterValidator(_registered)]
"""A controller of :mod:`hydroarm.control.registry`, stored under its canonical name."""


class SweepConfig(FrozenModel):
    """A whole sweep file (see the package docstring and ``examples/sweep.toml``).

    ``controllers``: names (case-insensitive: smc, mpc, gp-mpc); ``seeds``: a
    count n (seeds 0..n-1) or a list; ``mode``: ``grid`` (every combination of
    the parameters' values) or ``random`` (``samples`` points drawn with
    ``sampling_seed``: a list is a uniform choice, a range a uniform draw);
    ``base``: the settings of every run; ``mismatch``: the plant's rigid-body
    mismatch of every run; ``parameters``: dotted key -> list of values or
    :class:`Range`; ``save_trajectories``: also keep ``runs/<id>.npz``;
    ``metric``: the column the summary and the plots compare (default the mean
    E_p over joints; ``Ep_steady_mean`` leaves out the first 2 s);
    ``robustness``: the tracking bound of the summary's robustness table
    (:class:`Robustness`; an analysis setting: changing it recomputes no run).
    """

    name: str = pydantic.Field("sweep", min_length=1, max_length=200)
    description: str = ""
    controllers: list[ControllerName] = pydantic.Field(min_length=1)
    seeds: (
        Annotated[int, pydantic.Field(ge=1, le=MAX_RUNS)]
        | Annotated[list[pydantic.NonNegativeInt], pydantic.Field(min_length=1, max_length=MAX_RUNS)]
    ) = 1
    mode: Literal["grid", "random"] = "grid"
    samples: int | None = pydantic.Field(None, ge=1, le=MAX_RUNS)
    sampling_seed: int = pydantic.Field(0, ge=0)
    base: ExperimentConfig = ExperimentConfig()
    mismatch: Mismatch = Mismatch()
    parameters: dict[str, list[Any] | Range] = pydantic.Field(default_factory=dict)
    save_trajectories: bool = False
    metric: Literal[
        "Ep_mean", "Ep_steady_mean", "rms_mean", "max_error", "torque_rms_mean", "time_to_band_max", "step_ms_median"
    ] = "Ep_mean"
    robustness: Robustness = Robustness()

    @pydantic.field_validator("parameters", mode="before")
    @classmethod
    def _flatten(cls, value: Any) -> Any:
        return flatten_parameters(value) if isinstance(value, dict) else value

    @property
    def seed_list(self) -> list[int]:
        return list(range(self.seeds)) if isinstance(self.seeds, int) else list(self.seeds)


def flatten_parameters(parameters: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    """``{"mpc": {"r": [..]}}`` -> ``{"mpc.r": [..]}`` (TOML's unquoted dotted keys nest);
    a mapping with ``low``/``high`` is a :class:`Range`, not a level."""
    out: dict[str, Any] = {}
    for key, value in parameters.items():
        dotted = f"{prefix}{key}"
        if isinstance(value, Mapping) and not ({"low", "high"} & set(value)):
            out.update(flatten_parameters(value, dotted + "."))
        else:
            out[dotted] = value
    return out


def validate_sweep(data: Mapping[str, Any], source: str = "sweep", folder: Path | None = None) -> SweepConfig:
    """Validate a sweep mapping; errors name the field (``parameters.mpc.r``, ``controllers.1``).

    ``base`` may be a path to an experiment settings file (relative to ``folder``).
    """
    data = dict(data)
    if isinstance(data.get("base"), str):
        try:
            base = resolve_path(data["base"], folder)
            data["base"] = migrated(read_mapping(base), str(base))  # its schema = k, if any
        except ConfigError as error:
            raise ConfigError(f"{source}: base = {data['base']!r}: {error}") from None
    parameters = data.get("parameters", {})
    if isinstance(parameters, Mapping):
        parameters = flatten_parameters(parameters)
        for key, value in parameters.items():
            if isinstance(value, list) and not value:
                raise ConfigError(f"{source}: parameters.{key}: empty list: give at least one value")
            if not isinstance(value, (list, Mapping)):
                raise ConfigError(
                    f"{source}: parameters.{key} = {value!r}: give a list of values or a range "
                    "{low, high[, num][, log][, integer]}"
                )
            if isinstance(value, Mapping):
                try:
                    Range.model_validate(value)
                except pydantic.ValidationError as error:
                    problems = "; ".join(_range_problem(e) for e in error.errors())
                    raise ConfigError(f"{source}: parameters.{key}: {problems}") from None
        data["parameters"] = parameters
    config = validate(SweepConfig, data, source)
    check_sweep(config, source)
    return config


def _range_problem(error: Mapping[str, Any]) -> str:
    """One pydantic error of a :class:`Range` as ``field = value: what is allowed``."""
    where = ".".join(map(str, error["loc"]))
    if error["type"] == "extra_forbidden":
        return f"unknown key '{where}' (a range has low, high, num, log, integer)"
    message = error["msg"].removeprefix("Value error, ")
    return f"{where} = {error.get('input')!r}: {message}" if where else message


def check_sweep(config: SweepConfig, source: str = "sweep") -> None:
    """What the field types cannot say: mode/samples/range combinations, seeds, duplicates."""
    if len(set(config.controllers)) != len(config.controllers):
        raise ConfigError(f"{source}: controllers: a controller is listed twice ({config.controllers})")
    seeds = config.seed_list
    if len(set(seeds)) != len(seeds):
        raise ConfigError(f"{source}: seeds: a seed is listed twice ({seeds})")
    if config.mode == "grid" and config.samples is not None:
        raise ConfigError(f"{source}: samples: only for mode = 'random' (mode is 'grid')")
    if config.mode == "random":
        if config.samples is None:
            raise ConfigError(f"{source}: samples: missing: mode = 'random' needs the number of draws")
        if not config.parameters:
            raise ConfigError(f"{source}: parameters: mode = 'random' needs at least one parameter to draw")
    for key, value in config.parameters.items():
        if isinstance(value, list) and not value:
            raise ConfigError(f"{source}: parameters.{key}: empty list: give at least one value")
        if isinstance(value, Range):
            if config.mode == "grid" and value.num is None:
                raise ConfigError(f"{source}: parameters.{key}: a range in grid mode needs num (how many values)")
            if config.mode == "random" and value.num is not None:
                raise ConfigError(
                    f"{source}: parameters.{key}: num is for grid mode; random mode draws `samples` values"
                )


def load_sweep(path: str | Path) -> SweepConfig:
    """Read and validate a sweep file (TOML or YAML)."""
    path = Path(path)
    return validate_sweep(read_mapping(path), str(path), path.parent)


def resolve_path(value: str, folder: Path | None) -> Path:
    """``value`` relative to ``folder`` if such a file exists there, else as given (the cwd)."""
    path = Path(value)
    if folder is not None and not path.is_absolute() and (folder / path).exists():
        return folder / path
    return path
