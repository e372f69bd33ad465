"""Settings of the sliding-window GP: :class:`GPConfig` (the ``gp`` section of the experiment
settings).

Defaults are the paper's where it gives a value (window 10, theta0 = 1, no target scaling)
and measured choices otherwise (docs/controllers.md, "The GP: measured choices").
"""

from __future__ import annotations

import math
from typing import Annotated

import pydantic
from pydantic import StrictFloat

from hydroarm.config import FrozenModel, field_error

__all__ = ["GPConfig"]

LogBound = Annotated[StrictFloat, pydantic.Field(ge=-100.0, le=100.0)]
"""A natural-log bound, within [-100, 100]: exp(100) ~ 2.7e43, wider bounds overflow the kernel."""

LogBounds = Annotated[tuple[LogBound, LogBound], pydantic.Strict(False)]
"""A (low, high) pair of natural logs: a list is accepted (TOML, YAML and ``--set`` have no
tuples), its items are strict (``[true, 1.0]`` is refused)."""

Scales = Annotated[tuple[Annotated[StrictFloat, pydantic.Field(ge=1e-6, le=1e6)], ...], pydantic.Strict(False)]
"""Divisors in [1e-6, 1e6] (at least one): a list is accepted, its items are strict (see `LogBounds`)."""

Theta = Annotated[tuple[Annotated[StrictFloat, pydantic.Field(gt=0.0)], ...], pydantic.Strict(False)]
"""[sf2, sn2, l_1..l_d] (at least 3), natural scale, each > 0: a list is accepted, its items are strict."""

_BOUNDS = ("log_sf2_bounds", "log_sn2_bounds", "log_lengthscale_bounds")


class GPConfig(FrozenModel):
    """Validated, immutable settings of `SlidingWindowGP` (paper Algorithm 1 + our safeguards).

    sf2 and sn2 are in fitted target units^2 (N^2 m^2 for raw torques; unit-free with
    ``normalize_y`` or ``output_scale``), lengthscales in scaled input units (inputs divided
    by ``input_scale``). The lengths of ``theta0`` (d + 2: the kernel's description,
    :class:`~hydroarm.control.gp.kernels.SEARDKernel`), ``input_scale`` (d) and ``output_scale``
    (1 or n_outputs) are checked when the GP is built, as only then is d known
    (:meth:`size_problems`).
    """

    window: int = pydantic.Field(
        10, ge=2, le=1000, description="N_train, the samples kept in the window, paper 10 (samples)"
    )
    hyper_steps: int = pydantic.Field(
        1, ge=0, le=100, description="gradient-ascent steps on the LML per update, 0: fixed hyperparameters (steps)"
    )
    learning_rate: float = pydantic.Field(0.1, gt=0.0, description="log-space step per unit of dL/dlog(theta) (-)")
    max_log_step: float = pydantic.Field(
        1.0, gt=0.0, description="cap on the change of a log-hyperparameter per step (natural-log units)"
    )
    max_step_halvings: int = pydantic.Field(
        1, ge=0, le=20, description="halvings of a step that would lower the LML before it is rejected (-)"
    )
    grad_tol: float = pydantic.Field(
        0.0,
        ge=0.0,
        description="the paper's epsilon: an output stops when max |dL/dlog theta| <= grad_tol, 0: always step (-)",
    )
    log_sf2_bounds: LogBounds = pydantic.Field(
        (math.log(1e-4), math.log(1e8)), description="(low, high) natural-log box bounds of sf2 (target units^2)"
    )
    log_sn2_bounds: LogBounds = pydantic.Field(
        (math.log(1e-6), math.log(1e6)), description="(low, high) natural-log box bounds of sn2 (target units^2)"
    )
    log_lengthscale_bounds: LogBounds = pydantic.Field(
        (math.log(1e-2), math.log(1e3)),
        description="(low, high) natural-log box bounds of every lengthscale (input units)",
    )
    theta0: Theta | None = pydantic.Field(
        None,
        description=(
            "initial [sf2, sn2, l_1..l_d] of every output, within the bounds; null: all ones, the paper's "
            "(target units^2, input units)"
        ),
    )
    normalize_y: bool = pydantic.Field(
        False, description="standardise each output's window targets by their mean and population std (on/off)"
    )
    input_scale: Scales | None = pydantic.Field(
        None, description="per-input divisors applied before the kernel; null: 1 (input units)"
    )
    output_scale: Scales | None = pydantic.Field(
        None, description="divisor of the targets, one or one per output; null: 1 (target units)"
    )
    jitter: float = pydantic.Field(1e-10, ge=0.0, description="added to the training diagonal (target units^2)")
    max_jitter_retries: int = pydantic.Field(
        4, ge=0, le=20, description="retries with a growing extra diagonal after a failed Cholesky (-)"
    )
    incremental_min_window: int = pydantic.Field(
        30, ge=2, description="window size from which its factor is updated in O(N^2) at fixed theta (samples)"
    )
    refactor_every: int = pydantic.Field(
        100, ge=1, description="consecutive O(N^2) updates before a full refactorisation (updates)"
    )

    @pydantic.model_validator(mode="after")
    def _check_across_fields(self) -> GPConfig:
        """Vectors long enough, bounds ordered and holding theta0 (or 1 if theta0 is None),
        one target scaling. (The lengths are checked here, after the items: a length
        constraint on the type would count only the valid items.)"""
        if self.theta0 is not None and len(self.theta0) < 3:
            raise field_error("theta0", self.theta0, "must be None or d+2 >= 3 values [sf2, sn2, l_1..l_d]")
        for name in ("input_scale", "output_scale"):
            if getattr(self, name) == ():
                raise field_error(name, (), "must be None or at least one value")
        for name in _BOUNDS:
            low, high = getattr(self, name)
            if not low < high:
                raise field_error(name, (low, high), "must be (low, high) natural-log values with low < high")
        if self.theta0 is not None:
            theta0 = self.theta0
            names = ["sf2", "sn2"] + [f"l_{j + 1}" for j in range(len(theta0) - 2)]
            fields = ["log_sf2_bounds", "log_sn2_bounds"] + ["log_lengthscale_bounds"] * (len(theta0) - 2)
            for name, entry, field_name in zip(names, theta0, fields):
                low, high = getattr(self, field_name)
                if not low <= math.log(entry) <= high:
                    raise field_error(
                        "theta0",
                        theta0,
                        f"entry {name} = {entry!r} must lie within exp({field_name} = {(low, high)!r}) "
                        f"= [{math.exp(low):.3g}, {math.exp(high):.3g}]",
                    )
        else:
            for name in _BOUNDS:
                low, high = getattr(self, name)
                if not low <= 0.0 <= high:
                    raise field_error(name, (low, high), "must contain 0 (theta0=None initialises theta to 1)")
        if self.normalize_y and self.output_scale is not None:
            raise field_error(
                "output_scale", self.output_scale, "must be None when normalize_y is True (choose one target scaling)"
            )
        return self

    def size_problems(self, n_inputs: int, n_outputs: int) -> dict[str, str]:
        """What does not fit a GP of ``n_inputs`` inputs and ``n_outputs`` outputs: field ->
        what is wrong, for ``theta0`` (one value per entry of the kernel's description,
        :class:`~hydroarm.control.gp.kernels.SEARDKernel`), ``input_scale`` (one per input) and
        ``output_scale`` (1 or one per output); empty if everything fits."""
        from hydroarm.control.gp.kernels import SEARDKernel

        problems = {}
        if self.theta0 is not None:
            problem = SEARDKernel.for_config(self, n_inputs).check_theta(self.theta0)
            if problem is not None:
                problems["theta0"] = problem
        if self.input_scale is not None and len(self.input_scale) != n_inputs:
            problems["input_scale"] = f"{len(self.input_scale)} values: give one per input ({n_inputs})"
        if self.output_scale is not None and len(self.output_scale) not in (1, n_outputs):
            problems["output_scale"] = f"{len(self.output_scale)} values: give 1 or one per output ({n_outputs})"
        return problems
