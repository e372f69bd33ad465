"""Section 3: how the GP step, the MPC step and the plant step grow with their size.

GP step vs window, MPC step vs horizon, plant step vs Gauss points per cylinder, each
with the growth exponent (least-squares slope of log median time on log size). The
settings are the paper scenario's with one dotted-key override each, built by
:func:`hydroarm.sim.experiment.build_experiment`.
"""

from __future__ import annotations

import numpy as np

from hydroarm_bench.gp_peers import replay_ours
from hydroarm_bench.loop import paper_config, paper_experiment
from hydroarm_bench.stats import FULL_SAMPLES, growth_exponent, stats_ms, time_calls

GP_WINDOWS = (10, 20, 50, 100, 200)
MPC_HORIZONS = (5, 10, 20, 40)
QUADRATURE_POINTS = (2, 4, 8, 16, 32)


def _gp_window(events: list, quick: bool) -> dict:
    n_inputs, n_outputs = events[0][1].size, events[0][2].size
    rows = []
    for window in GP_WINDOWS:
        gp_config = paper_config(overrides={"gp.window": window}).gp
        limit = (10 if window >= 100 else 30) if quick else FULL_SAMPLES
        seconds, _ = replay_ours(events, gp_config, n_inputs, n_outputs, max_steps=limit)
        rows.append({"window": window, **stats_ms(seconds)})
    return {
        "what": f"GP step (add + 1 hyperparameter step + predict), {n_outputs} outputs, {n_inputs} inputs, "
        "closed-loop stream",
        "rows": rows,
        "growth_exponent": growth_exponent(GP_WINDOWS, [r["median"] for r in rows]),
    }


def _mpc_horizon(traj, quick: bool) -> dict:
    """The MPC driven along the recorded GP-MPC states (no plant in the loop)."""
    steps = 50 if quick else FULL_SAMPLES
    rows = []
    for horizon in MPC_HORIZONS:
        experiment = paper_experiment("MPC", overrides={"mpc.horizon": horizon})
        mpc, reference = experiment.controller, experiment.reference
        for k in range(10):
            mpc.compute(float(traj.t[k]), traj.y[k], reference)
        seconds = []
        for k in range(min(steps, len(traj.t))):
            out = mpc.compute(float(traj.t[k]), traj.y[k], reference)
            seconds.append(out.timings["total"])
        rows.append({"horizon": horizon, **stats_ms(seconds)})
    return {
        "what": "MPC step (compute) along the states of the GP-MPC closed loop",
        "rows": rows,
        "growth_exponent": growth_exponent(MPC_HORIZONS, [r["median"] for r in rows]),
    }


def _plant_quadrature(traj, quick: bool) -> dict:
    count = 20 if quick else FULL_SAMPLES
    picks = np.linspace(0, len(traj.t) - 1, min(count, len(traj.t))).astype(int)
    states = [(float(traj.t[k]), traj.x[k], traj.u[k]) for k in picks]
    rows = []
    for quadrature in QUADRATURE_POINTS:
        # the plant of the scenario (the controller is not used: SMC is the cheapest to build)
        experiment = paper_experiment("SMC", overrides={"water.quadrature_points": quadrature})
        plant, period = experiment.plant, experiment.control_period
        for t, x, u in states[:5]:
            plant.step(t, x, u, period)
        seconds = time_calls(lambda t, x, u, plant=plant, period=period: plant.step(t, x, u, period), states)
        rows.append({"quadrature_points": quadrature, **stats_ms(seconds)})
    return {
        "what": "plant step over one 10 ms control period (10 RK4 steps)",
        "rows": rows,
        "growth_exponent": growth_exponent(QUADRATURE_POINTS, [r["median"] for r in rows]),
    }


def bench_scaling(events: list, recorded: dict, quick: bool) -> dict:
    traj = recorded["GP-MPC"]["traj"]
    return {
        "gp_window": _gp_window(events, quick),
        "mpc_horizon": _mpc_horizon(traj, quick),
        "plant_quadrature": _plant_quadrature(traj, quick),
    }
