"""Section 2c: the true plant against the dry rigid body alone (Pinocchio ABA).

One dynamics evaluation (rigid body + water) against ``pinocchio.aba``, one control
period of :class:`~hydroarm.model.arm.plant.UnderwaterPlant` against the dry
:class:`~hydroarm.model.dynamics.nominal.NominalModel` RK4 step, and the compiled plant step
against its plain-NumPy twin ``UnderwaterPlant.step_numpy`` (bit-identical), at
states of the GP-MPC closed loop.
"""

from __future__ import annotations

import numpy as np

from hydroarm_bench.loop import paper_experiment
from hydroarm_bench.stats import FULL_SAMPLES, ratio, stats_ms, time_calls


def bench_plant(recorded: dict, quick: bool) -> dict:
    import pinocchio as pin

    from hydroarm.model.dynamics.nominal import NominalModel

    # the plant of the paper scenario (the controller is not used: SMC is the cheapest to build)
    experiment = paper_experiment("SMC")
    config, arm, plant = experiment.config, experiment.arm, experiment.plant
    traj = recorded["GP-MPC"]["traj"]
    count = 100 if quick else FULL_SAMPLES
    rows = np.linspace(0, len(traj.t) - 1, min(count, len(traj.t))).astype(int)
    n = arm.n_joints
    states = [(float(traj.t[k]), traj.x[k], traj.u[k]) for k in rows]
    nominal = NominalModel(arm, config.plant.inner_step)
    period = config.control_period
    model, data = arm.model, arm.create_data()
    wm = plant.water_model
    for t, x, u in states[:20]:  # warm-up
        plant.step(t, x, u, period)
        nominal.step(t, x, u, period)
    evaluation_water = time_calls(lambda t, x, u: wm.dynamics(x[:n], x[n:], u, t), states)
    evaluation_aba = time_calls(lambda t, x, u: pin.aba(model, data, x[:n], x[n:], u), states)
    step_plant = time_calls(lambda t, x, u: plant.step(t, x, u, period), states)
    step_dry = time_calls(lambda t, x, u: nominal.step(t, x, u, period), states)
    numpy_states = states[:20] if quick else states
    step_numpy = time_calls(lambda t, x, u: plant.step_numpy(t, x, u, period), numpy_states)
    worst = max(
        float(np.abs(plant.step(t, x, u, period)[0] - plant.step_numpy(t, x, u, period)[0]).max())
        for t, x, u in numpy_states
    )
    water, aba = stats_ms(evaluation_water), stats_ms(evaluation_aba)
    full, dry, twin = stats_ms(step_plant), stats_ms(step_dry), stats_ms(step_numpy)
    steps = int(round(period / config.plant.inner_step))
    return {
        "setting": f"{config.water.quadrature_points} Gauss points per cylinder, RK4 inner step "
        f"{config.plant.inner_step * 1e3:g} ms, control period {period * 1e3:g} ms ({4 * steps} dynamics evaluations)",
        "evaluation_water_plus_rigid_body_ms": water,
        "evaluation_rigid_body_aba_ms": aba,
        "evaluation_water_cost_ratio": ratio(water["median"], aba["median"]),
        "plant_step_ms": full,
        "dry_rigid_body_step_ms": dry,
        "plant_step_cost_ratio_vs_dry": ratio(full["median"], dry["median"]),
        # the keys keep their first names: "reference" is the plain-NumPy twin, step_numpy
        "plant_step_reference_ms": twin,
        "plant_step_speedup_vs_reference": ratio(twin["median"], full["median"]),
        "plant_step_max_abs_diff_vs_reference": worst,
    }
