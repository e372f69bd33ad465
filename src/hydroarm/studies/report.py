"""report.md of a reproduction: settings, tables, figures, and where and why we differ.

Every sentence that states a result is computed from ``metrics`` (summary.json's content, so
the report never claims what the numbers do not show); the module reads nothing else of the
study (:mod:`hydroarm.studies.reproduce` calls :func:`render_report`).

On the paper's arm the report sets the paper's numbers beside ours and appends
report_notes.md (prose about that arm). On any other arm neither says anything about it, so
the header, the noise floor and the notes are computed from that arm's own numbers
(``metrics["settings"]["arm"]``, :func:`~hydroarm.studies.reproduce.arm_summary`) and the
controllers are compared on that arm alone.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from hydroarm.control.estimator import EstimatorConfig, JointKalmanFilter
from hydroarm.control.registry import PAPER_CONTROLLERS
from hydroarm.control.smc import SMCConfig
from hydroarm.studies.figures import ANIMATION, FIGURES


def _ordering_sentence(block: dict, case: str) -> str:
    """The measured ordering and gains of one table; the paper's gain beside ours only when
    the table has it (runs on the paper's arm)."""
    ep = {name: np.asarray(block[name]["Ep"]) for name in PAPER_CONTROLLERS}
    means = {name: float(ep[name].mean()) for name in PAPER_CONTROLLERS}
    order = " < ".join(sorted(PAPER_CONTROLLERS, key=lambda n: means[n]))
    gp_beats_mpc = [j + 1 for j in range(len(ep["MPC"])) if ep["GP-MPC"][j] < ep["MPC"][j]]
    mpc_beats_smc = [j + 1 for j in range(len(ep["MPC"])) if ep["MPC"][j] < ep["SMC"][j]]
    gain = block["gain_gp_mpc_over_mpc_percent"]
    bound = block["MPC_dry_arm_bound"]
    per_joint = ", ".join(f"{g:.1f}" for g in bound["gain_over_MPC_percent"])
    return (
        f"- **{case}**: mean E_p ordering {order} "
        f"({', '.join(f'{n} {means[n]:.4g}' for n in PAPER_CONTROLLERS)} rad^2). "
        f"GP-MPC beats MPC on joints {gp_beats_mpc or 'none'}; MPC beats SMC on joints {mpc_beats_smc or 'none'}. "
        f"GP-MPC's gain over MPC: {gain['mean_of_joints']:.1f} % as the paper averages it "
        + (
            f"(mean of the per-joint gains; paper {gain['paper_mean_of_joints']} %), "
            if "paper_mean_of_joints" in gain
            else "(mean of the per-joint gains), "
        )
        + f"{gain['of_mean_Ep']:.1f} % on the mean E_p, "
        f"{np.mean(gain['steady_per_joint']):.1f} % after the start-up (t > 2 s). "
        f"Perfect disturbance knowledge (the same MPC on the arm without water) would gain "
        f"{bound['gain_mean_of_joints']:.1f} % (per joint: {per_joint})."
    )


def _best_sentence(block: dict, case: str) -> str:
    """What hydroarm's flagship row achieves in one table, computed from ``block``."""
    best = block.get("best")
    if best is None:
        return ""
    row = block[best["row"]]
    smc = block["SMC"]
    ratios = best["steady_ratio_SMC_over_best"]
    loses = [j + 1 for j in range(len(row["Ep"])) if j + 1 not in best["joints_beaten_vs_SMC"]]
    return (
        f"- **{case}**: {best['row']} has mean E_p {row['Ep_mean']:.4g} rad^2 (SMC {smc['Ep_mean']:.4g}, "
        f"SMC+KF {block['SMC+KF']['Ep_mean']:.4g}); it beats "
        f"{', '.join(best['beats_on_mean_Ep']) or 'no row'} on the mean"
        + (f" and loses to {', '.join(best['loses_on_mean_Ep_to'])}" if best["loses_on_mean_Ep_to"] else "")
        + f". Against the SMC it is better on joints {best['joints_beaten_vs_SMC'] or 'none'}"
        + (f" and worse on joints {loses}" if loses else "")
        + "; after the start-up (t > 2 s) the SMC's E_p is "
        + ", ".join(f"{r:.3g}x" for r in ratios)
        + " its own, joint by joint"
        + (
            ", the SMC+KF's (same estimator) " + ", ".join(f"{r:.3g}x" for r in best["steady_ratio_SMCKF_over_best"])
            if "steady_ratio_SMCKF_over_best" in best
            else ""
        )
        + "."
    )


def _estimator_floor(metrics: dict, noisy: dict) -> list[str]:
    """Lines on the Kalman filter's own error floor in the noisy table (computed, not quoted)."""
    best = noisy.get("best")
    experiment = metrics["settings"]["experiment"]
    variance = metrics["settings"].get("noise_variance")
    if best is None or not variance:
        return []
    config = EstimatorConfig.model_validate(experiment.get("estimator", {})).for_sensor(variance)
    posterior = JointKalmanFilter(1, experiment["control_period"], config).posterior_covariance
    ours = np.asarray(noisy[best["row"]]["Ep_steady"])
    smc_kf = np.asarray(noisy["SMC+KF"]["Ep_steady"])
    return [
        "The filter is designed for the sensor: on the noise-free one it passes the measurement through (the",
        "clean `+ Kalman filter` rows equal the plain ones). On the noisy sensor its steady-state position",
        f"error variance is {posterior[0, 0]:.2g} rad^2 per joint (its Riccati solution), a floor under the E_p",
        f"after 2 s of any controller acting on the estimate: {best['row']} sits at {ours.min():.2g}-{ours.max():.2g},",
        f"so after 2 s its lead over the SMC+KF is bounded by the SMC+KF's own E_p over that floor "
        f"({', '.join(f'{x / posterior[0, 0]:.3g}x' for x in smc_kf)} per joint).",
    ]


def _value(value) -> str:
    """A setting as the report shows it: ``:g`` for a number, a list as ``[a, b, ...]``."""
    if isinstance(value, list):
        return "[" + ", ".join(_value(v) for v in value) + "]"
    return f"{value:g}" if isinstance(value, (int, float)) and not isinstance(value, bool) else str(value)


def _paper_header(metrics: dict) -> tuple[list[str], list[str]]:
    """Title, introduction and the arm/task/SMC settings lines of a reproduction on the paper's arm."""
    experiment = metrics["settings"]["experiment"]
    smc = experiment["smc"]
    return [
        "# Reproduction of Liu et al. 2023 (J. Mar. Sci. Eng. 11, 1641)",
        "",
        "Adaptive MPC with a sliding-window Gaussian process on a 6-DOF underwater arm, compared with",
        "plain MPC and sliding-mode control, without (Table 1) and with (Table 2) measurement noise.",
    ], [
        f"- Arm `{experiment['arm']}` (paper Tables A1-A2), true plant = ",
        f"- Task: eq. (21), first six terms, {experiment['duration']:g} s from rest at q = 0; control period "
        f"{experiment['control_period'] * 1e3:g} ms; torque limit from the arm file.",
        f"- SMC: lambda = {smc['surface_slope']}, k = {smc['switching_gain']}, "
        f"phi = {smc['boundary_layer']}, k_s = {smc['linear_gain']} (best of a grid, tuned on the dry arm).",
    ]


# Another arm than the paper's: the header, the noise floor and the notes from its own numbers


def _limits(limits: list[float]) -> str:
    """``9 N m`` if every joint has the same limit, else ``9, 9, 4 N m``."""
    values = sorted(set(limits))
    return f"{values[0]:g} N m" if len(values) == 1 else ", ".join(f"{x:g}" for x in limits) + " N m"


def _finite(values) -> bool:
    return all(v is not None and math.isfinite(v) for v in np.ravel(values))


def _arm_header(metrics: dict) -> tuple[list[str], list[str]]:
    """The title and introduction, and the arm, task and SMC lines of the settings."""
    settings = metrics["settings"]
    experiment, arm = settings["experiment"], settings["arm"]
    name, joints = arm["name"], arm["joints"]
    described = f"{arm['description']}; " if arm.get("description") else ""
    smc = experiment["smc"]
    default_smc = smc == SMCConfig().model_dump(mode="json")
    title = [
        f"# The study of Liu et al. 2023 on the arm `{name}`",
        "",
        "Sliding-mode control, MPC and the paper's MPC with a sliding-window Gaussian process (GP-MPC),",
        f"with hydroarm's flagship, on the arm `{name}` ({described}{joints} joints, torque limit",
        f"{_limits(arm['torque_limit'])}), without (Table 1) and with (Table 2) measurement noise. The paper's",
        "numbers belong to its own 6-joint arm and are not shown here:",
        "`hydroarm reproduce --out results` compares with them on that arm.",
    ]
    lines = [
        f"- Arm `{name}`: {joints} joints, torque limit {_limits(arm['torque_limit'])} (from the arm file); "
        "true plant = ",
        "- Task: the paper's eq. (21) shape scaled to the arm's joint ranges (joint i follows the paper's "
        f"joint i mod 6, within 80 % of each range; `task_for_arm`), {experiment['duration']:g} s from rest at "
        f"its start; control period {experiment['control_period'] * 1e3:g} ms.",
        f"- SMC: lambda = {smc['surface_slope']}, k = {smc['switching_gain']}, phi = {smc['boundary_layer']}, "
        f"k_s = {smc['linear_gain']} "
        + (
            "(hydroarm's defaults, tuned on the paper's arm, not on this one: `hydroarm tune --arm "
            f"{name} --controller smc --out {name}.toml` tunes them for it, `--config {name}.toml` uses them)."
            if default_smc
            else "(as set)."
        ),
    ]
    return title, lines


def _arm_noise_floor(metrics: dict) -> list[str]:
    """What one-step residuals cannot resolve on this arm: M_jj / T times the velocity noise of
    two samples, for the joint with the largest inertia at the start."""
    settings = metrics["settings"]
    inertia = np.asarray(settings["arm"]["inertia_diagonal_at_start"], dtype=float)
    period = settings["experiment"]["control_period"]
    std = math.sqrt(settings["noise_variance"])
    j = int(np.argmax(inertia))
    two = math.sqrt(2.0) * std
    return [
        f"Noise floor: a velocity noise of standard deviation {std:.3g} rad/s on two consecutive samples puts",
        f"about M_{j + 1}{j + 1} / T * {two:.2g} ~ {inertia[j] / period * two:.2g} N m of noise on each one-step "
        f"torque residual of joint {j + 1}",
        f"(M_{j + 1}{j + 1} = {inertia[j]:.3g} kg m^2 at the start, T = {period * 1e3:g} ms), which no estimator "
        "working from one-step residuals can fall below per sample.",
    ]


def _share(ep: list[float]) -> tuple[int, float]:
    """The joint (1-based) with the largest E_p and its share of the sum (%)."""
    values = np.asarray(ep, dtype=float)
    j = int(np.argmax(values))
    total = float(values.sum())
    return j + 1, 100.0 * values[j] / total if total > 0 else 0.0


def _arm_notes(metrics: dict) -> list[str]:
    """Notes on this arm, every number from ``metrics``."""
    settings = metrics["settings"]
    limits = np.asarray(settings["arm"]["torque_limit"], dtype=float)
    clean = metrics["clean"]
    rows = [*PAPER_CONTROLLERS, clean["best"]["row"]]  # hydroarm's best row, as summary.json names it
    lines = [f"## Notes on the arm `{settings['arm']['name']}` (computed from its runs)", ""]
    where = ", ".join(
        "{}'s on joint {} ({:.0f} % of its sum)".format(name, *_share(clean[name]["Ep"])) for name in rows
    )
    lines.append(f"- **Where the error is** (no noise): the largest E_p is {where}.")
    peaks = []
    for name in rows:
        peak = np.asarray(clean[name].get("torque_max", [math.nan] * len(limits)), dtype=float)
        if not _finite(peak):
            continue
        use = peak / limits
        j = int(np.argmax(use))
        at_limit = [k + 1 for k in range(len(use)) if use[k] >= 0.999]
        text = f"{name} {peak[j]:.3g} N m on joint {j + 1} ({100 * use[j]:.0f} % of its limit)"
        peaks.append(text + (f", at the limit on joints {at_limit}" if at_limit else ""))
    if peaks:
        lines.append(f"- **Torque against the limit** (no noise, peak |tau|): {'; '.join(peaks)}.")
    steady = [(name, clean[name]["Ep_steady"], clean[name]["Ep_mean"]) for name in rows]
    if all(_finite(s) for _, s, _ in steady):
        parts = ", ".join(
            f"{name} {np.mean(s):.3g} rad^2 ({100 * np.mean(s) / m:.2g} % of its whole-run mean)" if m > 0 else name
            for name, s, m in steady
        )
        lines.append(f"- **After the start-up** (t > 2 s, no noise) the mean E_p is {parts}.")
    gains = {case: metrics[case]["gain_gp_mpc_over_mpc_percent"] for case in ("clean", "noisy")}
    lines.append(
        f"- **What the GP adds to the MPC**: {gains['clean']['of_mean_Ep']:.1f} % on the mean E_p without noise, "
        f"{gains['noisy']['of_mean_Ep']:.1f} % with noise. The same MPC on the arm without water (perfect "
        f"disturbance knowledge) gains {clean['MPC_dry_arm_bound']['gain_mean_of_joints']:.1f} % as the paper "
        "averages it: the ceiling for any disturbance estimate feeding this MPC."
    )
    rms = clean["GP-MPC"].get("disturbance_rms_after_1s")
    if rms is not None and _finite(rms):
        j = int(np.argmax(rms))
        lines.append(
            f"- **How much the water matters**: after 1 s the disturbance's RMS is at most {rms[j]:.3g} N m "
            f"(joint {j + 1}), {100 * rms[j] / limits[j]:.2g} % of that joint's torque limit."
        )
    return [*lines, ""]


# The report


def reproducible_digits(metrics: dict) -> list[str]:
    """What the report says of the digits that reproduce across machines, from summary.json's
    replicas (docs/data/reproducibility.md has the measurement across BLAS kernels)."""
    clean = metrics["clean"]
    lines = [
        "### Which digits reproduce on another machine",
        "",
        "Same command, same package versions, same machine: the same numbers, bit for bit. Across CPUs",
        "(OpenBLAS's kernel, numba's target) the learners' algebra is fixed-order compiled code (no BLAS,",
        "LAPACK or CPU-dispatched NumPy function), but the rest of the loop (the MPC's products, the",
        "estimator) still rounds by the CPU's BLAS kernel, at about 1e-11 relative in these rows. The",
        "sliding-window GP's rows turn such a last-bit difference into another run (each step accepts or",
        "rejects a hyperparameter step on a comparison of two likelihoods), and so does PI-IDMPC's planner",
        "(its plans' active sets follow its learned model): these rows are reported as a",
        "distribution and printed with the digits it leaves.",
        "",
    ]
    replicated = [(name, clean[name]["replicas"]) for name in clean if isinstance(clean[name], dict)
                  and "replicas" in clean[name]]  # fmt: skip
    if not replicated:
        return [*lines, "(This run has no replicas: `--replicas 1`; its GP rows' digits are those of one run.)", ""]
    count = replicated[0][1]["count"]
    offset = replicated[0][1]["offset_rad"]
    lines += [
        f"Clean case: each of these rows ran {count} times, from the task's start and from starts moved by",
        f"up to {offset:g} rad per joint; the spread (std over the runs) of E_p, largest over the joints",
        "relative to the mean, and of the mean over joints:",
        "",
        "| row | largest relative spread of a joint | mean of joints |",
        "|---|---|---|",
    ]
    for name, replicas in replicated:
        relative = [e / m if m > 0 else 0.0 for e, m in zip(replicas["Ep_spread"], replicas["Ep_mean"])]
        mean = replicas["Ep_mean_of_joints"]
        lines.append(f"| {name} | {max(relative):.2g} | {mean:.4g} ± {replicas['Ep_mean_of_joints_spread']:.2g} |")
    lines += [
        "",
        "Noisy case: the seeds are the replicas; those rows show their mean over the seeds and its",
        "standard error. Every other row's numbers agree across BLAS kernels to about 1e-10 relative",
        "(docs/data/reproducibility.md).",
        "",
    ]
    if metrics.get("ablation") or metrics.get("ablation_idmpc"):
        lines += [
            "The ablations' GP-MPC and GP-IDMPC numbers are single runs from the task's start (not",
            "replicated: K runs for each of their settings would multiply the ablation's time by K). Their",
            "loops are as sensitive, and some settings more than the rows above: under another BLAS kernel",
            "they were measured to move by up to 73 % (docs/data/reproducibility.md). Read them as one",
            "draw each, not to their digits; their MPC and IDMPC numbers hold like the rows above.",
            "",
        ]
    return lines


def render_report(metrics: dict, out: Path) -> str:
    """report.md. On the paper's arm (``settings.paper_arm``): the reproduction, the paper's
    numbers beside ours and report_notes.md; on any other arm: the same study on that arm,
    with no paper numbers and notes computed from its own (the module docstring)."""
    settings = metrics["settings"]
    clean, noisy = metrics["clean"], metrics["noisy"]
    paper = settings.get("paper_arm", True)
    title, (arm_line, task_line, smc_line) = _paper_header(metrics) if paper else _arm_header(metrics)
    lines = [
        *title,
        "",
        f"Wall time: {metrics['wall_time_s']['total']:.1f} s for all runs, tables and figures "
        f"({settings['workers']} worker processes; {metrics['machine']['cpus']} CPUs; "
        f"Python {metrics['machine']['python']}).",
        "",
        "Results files: `summary.json` holds every number (the rows, the ablations, the settings, the",
        "arm, wall times): read this one. `metrics.json` holds only Tables 1-2's numbers (summary.json's",
        "`clean` and `noisy`). Both are strict JSON: a number that is not defined (e.g. E_p after 2 s of a",
        "shorter run) is `null`.",
        "",
        *_settings_section(metrics, arm_line, task_line, smc_line),
        "## Results",
        "",
        _ordering_sentence(clean, "no noise (Table 1)"),
        _ordering_sentence(noisy, "with noise (Table 2)"),
        "",
        "hydroarm's flagship, beside the paper's (docs/controllers.md): GP-IDMPC, an MPC in",
        "acceleration space on the exact double integrator with computed torque underneath and the GP's",
        "estimate fed forward, behind a Kalman filter per joint. The paper's controllers behind the same",
        "filter are the rows `+ Kalman filter`, so it is compared with each of them on the same estimator.",
        "It is the flagship because it keeps its control period, not because it is hydroarm's most",
        "accurate controller: in docs/controllers.md's table PI-IDMPC is below it on every arm but in the",
        "Reynolds water, and the best IDMPC + observer row is within 0.1 % of it on the paper task.",
        "",
        _best_sentence(clean, "no noise"),
        _best_sentence(noisy, "with noise"),
        "",
        *_estimator_floor(metrics, noisy),
        "",
        (out / "table1.md").read_text() if (out / "table1.md").exists() else "",
        (out / "table2.md").read_text() if (out / "table2.md").exists() else "",
        *_disturbance_section(metrics, paper),
        *_step_time_and_faults(metrics),
    ]
    if metrics.get("ablation") and (out / "ablation.md").exists():
        lines += ["## Ablation", "", (out / "ablation.md").read_text()]
    if metrics.get("ablation_idmpc") and (out / "ablation_idmpc.md").exists():
        lines += [(out / "ablation_idmpc.md").read_text()]
    lines += ["## Figures", ""]
    lines += [f"![GP-MPC on the task: the arm (colour) and the reference (grey)]({ANIMATION})", ""]
    for name, title in FIGURES.items():
        lines.append(f"![{title}]({name})")
        lines.append("")
    if paper:
        lines += [Path(__file__).with_name("report_notes.md").read_text()]
    else:
        lines += _arm_notes(metrics)
    return "\n".join(lines) + "\n"


def _settings_section(metrics: dict, arm_line: str, task_line: str, smc_line: str) -> list[str]:
    """The report's Settings section: the plant, the task, the MPC, the GP, the SMC, the noise."""
    settings = metrics["settings"]
    experiment = settings["experiment"]
    water, mpc = experiment["water"], experiment["mpc"]
    gp_settings, gpmpc = experiment["gp"], experiment["gpmpc"]
    n = len(metrics["clean"]["MPC"]["Ep"])
    return [
        "## Settings",
        "",
        arm_line + "Pinocchio rigid body + Morison water "
        f"(rho = {water['rho']:g}, C_d = {water['cd']:g}, C_m = {water['cm']:g}, "
        f"{water['quadrature_points']} Gauss points per cylinder) + buoyancy + the paper's current "
        f"(model `{water['current']['model']}`), RK4 with {experiment['plant']['inner_step'] * 1e3:g} ms steps.",
        task_line,
        f"- MPC: N = {mpc['horizon']}, Q = diag({_value(mpc['q_position'])} x {n}, "
        f"{_value(mpc['q_velocity'])} x {n}), R = {_value(mpc['r'])} I, terminal cost from the DARE, "
        f"terminal set `{mpc['terminal_set']}`, solver {mpc['solver']}, "
        f"prediction model `{mpc.get('discretisation', 'euler')}` (docs/deviations.md).",
        f"- GP: window {gp_settings['window']}, {gp_settings['hyper_steps']} hyperparameter step(s) per control step, "
        f"features `{gpmpc['features']}`, estimate fed forward as `{gpmpc['feedforward']}`.",
        smc_line,
        f"- Noise: variance {settings['noise_variance']} on measured q and q' (Table 2), "
        f"{settings['noisy_seeds']} seeds; Table 2 shows the mean over seeds and its spread.",
        "",
    ]


def _disturbance_section(metrics: dict, paper: bool) -> list[str]:
    """The GP-MPC's disturbance estimate against the truth after 1 s, per joint, and the noise floor."""
    clean, noisy = metrics["clean"], metrics["noisy"]
    n = len(clean["MPC"]["Ep"])
    lines = [
        "### Disturbance estimate (paper: converges within 1 s, then within 0.1 N m)"
        if paper
        else "### Disturbance estimate of the GP-MPC",
        "",
        "| case | quantity | " + " | ".join(f"joint {j + 1}" for j in range(n)) + " |",
        "|---|---|" + "---|" * n,
    ]
    for case, block in (("no noise", clean), ("noise", noisy)):
        gp = block["GP-MPC"]
        lines.append(
            f"| {case} | RMS estimate error after 1 s (N m) | "
            + " | ".join(f"{x:.3g}" for x in gp.get("disturbance_estimate_rms_after_1s", [math.nan] * n))
            + " |"
        )
        lines.append(
            f"| {case} | RMS of the disturbance after 1 s (N m) | "
            + " | ".join(f"{x:.3g}" for x in gp.get("disturbance_rms_after_1s", [math.nan] * n))
            + " |"
        )
    lines += [""]
    lines += (
        [
            "Noise floor: a velocity noise of standard deviation 0.0316 rad/s on two consecutive samples puts",
            "about M_11 / T * 0.045 ~ 15 N m of noise on each one-step torque residual of joint 1, which no",
            "estimator working from one-step residuals can fall below per sample.",
        ]
        if paper
        else _arm_noise_floor(metrics)
    )
    return lines


def _step_time_and_faults(metrics: dict) -> list[str]:
    """The step-time table (clean runs), the reproducible digits and the faults met."""
    clean, noisy = metrics["clean"], metrics["noisy"]
    lines = [
        "",
        "### Step time",
        "",
        "| controller | median (ms) | p99 (ms) |",
        "|---|---|---|",
    ]
    for name in [n for n in clean if isinstance(clean[n], dict) and "step_ms_median" in clean[n]]:
        lines.append(f"| {name} | {clean[name]['step_ms_median']:.3f} | {clean[name]['step_ms_p99']:.3f} |")
    lines += ["", "(Measured inside the closed loop on a shared machine; `hydroarm bench` measures it properly.)", ""]
    lines += reproducible_digits(metrics)
    lines += ["### Faults met during the runs (docs/reliability.md)", ""]
    faults = [
        f"- {case}, {name}: " + ", ".join(f"{key} x {count}" for key, count in sorted(block[name]["faults"].items()))
        for case, block in (("no noise", clean), ("noise", noisy))
        for name in PAPER_CONTROLLERS
        if block[name].get("faults")
    ]
    lines += (faults or ["None: no measurement held, no GP or QP fallback, no clipped torque, no stopped run."]) + [""]
    return lines
