"""report.md of the study on an arm other than the paper's: header, noise floor and notes,
every sentence computed from that arm's numbers.

The paper's numbers (its 6-joint arm, 500 N m per joint) and report_notes.md (prose about
that arm) say nothing about another arm, so this report compares the controllers on the
arm alone. Reads ``metrics["settings"]["arm"]`` (:func:`~hydroarm.studies.reproduce.arm_summary`).
"""

from __future__ import annotations

import math

import numpy as np

from hydroarm.control.registry import PAPER_CONTROLLERS
from hydroarm.control.smc import SMCConfig
from hydroarm.studies.reproduce_tables import BEST


def _limits(limits: list[float]) -> str:
    """``9 N m`` if every joint has the same limit, else ``9, 9, 4 N m``."""
    values = sorted(set(limits))
    return f"{values[0]:g} N m" if len(values) == 1 else ", ".join(f"{x:g}" for x in limits) + " N m"


def _finite(values) -> bool:
    return all(v is not None and math.isfinite(v) for v in np.ravel(values))


def header(metrics: dict) -> tuple[list[str], list[str]]:
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
        f"with hydroarm's best controller, on the arm `{name}` ({described}{joints} joints, torque limit",
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


def noise_floor(metrics: dict) -> list[str]:
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


def notes(metrics: dict) -> list[str]:
    """Notes on this arm, every number from ``metrics``."""
    settings = metrics["settings"]
    limits = np.asarray(settings["arm"]["torque_limit"], dtype=float)
    clean = metrics["clean"]
    rows = [*PAPER_CONTROLLERS, BEST]
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
