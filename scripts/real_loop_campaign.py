"""The real-loop campaign (issue 23): which controller survives encoders, delay, friction, limits?

Runs every controller on the paper task (10 s, Table 1's noise-free sensor otherwise) in

* the grid of ``examples/real_loop.toml`` (the sweep file is the one source of the grid and its
  base, the target world: a 16-bit encoder measuring position only, one period of loop delay,
  the published joint friction; around it sensor delay 0-2, friction 0-2x, dropout 0/10 %), and
* each effect on its own, from the ideal loop (:data:`EFFECTS`), plus the target world with the
  drives' rate limit and bandwidth, and two flagship-only controls (no delay prediction; the
  filter's default sigma_a^2).

``--arm`` runs the same worlds on another arm's task (ur5, alpha5, or iiwa14: the 7-joint arm of
examples/urdf/iiwa14.urdf), the sweep file's base with only its arm changed: the same 16-bit
encoder, the same friction (the arm files carry none: every arm takes the published per-joint
values of :mod:`hydroarm.model.real_loop.friction`, Gaz et al. 2019's Panda, joint i for joint i),
and E_p relative to that arm's own ideal loop. The paper arm writes ``docs/data/real_loop.json``;
the other arms merge into one file (``--out docs/data/real_loop_arms.json``), keyed by arm.
Besides the registry's controllers the observer variants run (:data:`VARIANTS`: IDMPC, SMC and
MPC over the TDE or the NDOB, gated or not), named as in the learning study (``IDMPC+TDE-gated``).

Every run is on default settings (issue 32: no hand-set filter): ``estimator.kind = "auto"`` puts
every controller behind the Kalman filter wherever the sensor is not the ideal one or the loop has
a delay, with sigma_a^2 derived from the sensor; on the ideal sensor that filter passes the
measurement through, so the ideal loop's numbers are the reproduction's. Per run: diverged,
within the band (ran to the end and |q_r - q| < 0.5 rad on every joint from 2 s on), E_p (mean
over joints and samples, rad^2), and E_p relative to the same controller's ideal loop. Writes
``--out`` (JSON) and prints the tables.

Usage: python scripts/real_loop_campaign.py [--out docs/data/real_loop.json] [--workers 2]
       python scripts/real_loop_campaign.py --arm ur5 --out docs/data/real_loop_arms.json --workers 1 \
           --groups grid alone --controllers GP-IDMPC IDMPC --skip-worlds "rate limit 1000 N m/s"
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from hydroarm.control.registry import CONTROLLERS
from hydroarm.sim.experiment import ExperimentConfig, build_experiment, with_overrides
from hydroarm.studies.sweep.plan import plan_sweep
from hydroarm.studies.sweep.schema import load_sweep

ROOT = Path(__file__).resolve().parents[1]
SWEEP = ROOT / "examples" / "real_loop.toml"
BAND, AFTER = 0.5, 2.0  # rad, s: the stress study's bound
FLAGSHIP = "GP-IDMPC"
SIXTEEN_BIT = 2 * math.pi / 2**16
ARMS: dict[str, str] = {
    "paper": "paper",
    "ur5": "ur5",
    "alpha5": "alpha5",
    "iiwa14": "examples/urdf/iiwa14.urdf",
}
"""--arm's choices -> the arm (built-in name, or a path relative to the repository root)."""

OBSERVERS: dict[str, dict] = {
    "TDE": {"observer.kind": "tde"},
    "TDE-gated": {"observer.kind": "tde", "observer.gate": True},
    "NDOB": {"observer.kind": "ndob"},
    "NDOB-gated": {"observer.kind": "ndob", "observer.gate": True},
}
VARIANTS: dict[str, tuple[str, dict]] = {
    f"{name}+{label}": (name, overrides) for name in ("IDMPC", "SMC", "MPC") for label, overrides in OBSERVERS.items()
}
"""The observer variants: label -> (the registry's controller, its observer settings; every
other setting at its default, the NDOB's gain L = 0.1)."""
RATE_LIMIT = 1000.0  # N m/s: 10 N m per period, below the ideal loop's 95th percentile on joint 1 (1490 N m/s)
BANDWIDTH = 20.0  # Hz

EFFECTS: dict[str, dict] = {
    "ideal": {},
    "encoder-only 16 bit": {"sensor.velocity": "differenced", "sensor.resolution": SIXTEEN_BIT},
    "sensor delay 1": {"sensor.delay": 1},
    "sensor delay 2": {"sensor.delay": 2},
    "actuator delay 1": {"actuator.delay": 1},
    "friction 1x": {"friction.scale": 1.0},
    "friction 2x": {"friction.scale": 2.0},
    "dropout 10 %": {"sensor.dropout": 0.1},
    f"rate limit {RATE_LIMIT:g} N m/s": {"actuator.rate_limit": RATE_LIMIT},
    f"bandwidth {BANDWIDTH:g} Hz": {"actuator.bandwidth": BANDWIDTH},
}
"""Each effect alone, as overrides on the ideal loop (the sweep file's filter, no other effect)."""

TARGET_EXTRA: dict[str, dict] = {
    "target + rate limit + bandwidth": {"actuator.rate_limit": RATE_LIMIT, "actuator.bandwidth": BANDWIDTH},
    f"target + bandwidth {BANDWIDTH:g} Hz": {"actuator.bandwidth": BANDWIDTH},
    "target + actuator delay 1 (2 periods in all)": {"actuator.delay": 1},
}
"""Worlds on top of the target world (the sweep file's base)."""

CONTROLS: dict[str, dict] = {
    "target, no delay prediction": {"estimator.delay": 0},
    "target, sigma_a^2 = 100 (the filter's old default)": {"estimator.acceleration_variance": 100.0},
}
"""Flagship-only controls on the target world: what the predictor and the filter's derived sigma_a^2 are worth."""

SENSITIVITY_VARIANCE = 0.01
"""sigma_a^2 of the sensitivity group: the flagship's dropout-with-friction worlds with a slower filter."""


def arm_base(target: ExperimentConfig, arm: str) -> ExperimentConfig:
    """The sweep file's base on ``arm`` (a key of :data:`ARMS`): its arm alone changed."""
    path = ARMS[arm]
    return with_overrides(target, {"arm": str(ROOT / path) if path.endswith(".urdf") else path})


def ideal_base(target: ExperimentConfig) -> ExperimentConfig:
    """The ideal loop: every real-loop setting at its default (the target's filter settings, its defaults too)."""
    return ExperimentConfig(arm=target.arm, duration=target.duration, estimator=target.estimator)


def run(task: tuple[str, str, str, dict, dict, int]) -> dict:
    """One run: ``(group, world, controller or variant, base settings (JSON), overrides, seed)``."""
    group, world, controller, base, overrides, seed = task
    name, settings = VARIANTS.get(controller, (controller, {}))
    config = with_overrides(ExperimentConfig.model_validate(base), {**overrides, **settings})
    experiment = build_experiment(config, name)
    start = time.perf_counter()
    traj = experiment.run(seed)
    wall = time.perf_counter() - start
    error = np.abs(traj.q_ref - traj.q)
    finished = not traj.meta["stopped"] and len(traj.t) == int(round(config.duration / config.control_period))
    late = traj.t >= AFTER
    within = bool(finished and late.any() and np.max(error[late]) < BAND)
    return {
        "group": group,
        "world": world,
        "controller": controller,
        "overrides": overrides,
        "seed": seed,
        "diverged": bool(traj.diverged),
        "stopped": traj.meta["stopped"],
        "within_band": within,
        "Ep": float(np.mean(error**2)) if finished else None,
        "max_error_after_2s": float(np.max(error[late])) if finished else None,
        "max_error_after_2s_per_joint": np.max(error[late], axis=0).tolist() if finished else None,
        "inner_step_s": experiment.plant.inner_step,
        "dropped": (traj.meta.get("sensor") or {}).get("dropped", 0),
        "wall_s": wall,
    }


def tasks(arm: str = "paper", controllers: list[str] | None = None) -> list[tuple]:
    """Every run of the campaign on ``arm``: the sweep file's grid, each effect alone, the
    target world's extras for ``controllers`` (default: the registry's), the flagship's controls."""
    sweep = load_sweep(SWEEP)
    plan = plan_sweep(sweep, SWEEP.parent)
    target = sweep.base if arm == "paper" else arm_base(sweep.base, arm)
    ideal = ideal_base(target).model_dump(mode="json")
    target_json = target.model_dump(mode="json")
    names = list(CONTROLLERS) if controllers is None else controllers
    grid = list(dict.fromkeys((tuple(row.params.items()), row.seed) for row in plan.rows))
    out: list[tuple] = []
    for params, seed in grid:
        world = ", ".join(f"{k.split('.')[-1]}={v:g}" for k, v in params)
        out += [("grid", world, name, target_json, dict(params), seed) for name in names]
    for world, overrides in EFFECTS.items():
        out += [("alone", world, name, ideal, overrides, 0) for name in names]
    for world, overrides in TARGET_EXTRA.items():
        out += [("target+", world, name, target_json, overrides, 0) for name in names]
    for world, overrides in CONTROLS.items():
        out.append(("control", world, FLAGSHIP, target_json, overrides, 0))
    for row in plan.rows:
        if row.controller == FLAGSHIP and row.params["sensor.dropout"] > 0 and row.params["friction.scale"] > 0:
            world = ", ".join(f"{k.split('.')[-1]}={v:g}" for k, v in row.params.items())
            overrides = {**row.params, "estimator.acceleration_variance": SENSITIVITY_VARIANCE}
            out.append(
                ("sensitivity", f"{world}, sigma_a^2={SENSITIVITY_VARIANCE:g}", FLAGSHIP, target_json, overrides, 0)
            )
    return out


def ideal_ep(results: list[dict]) -> dict[str, float]:
    """Each controller's E_p in the ideal loop (rad^2): the reference of its E_p / ideal."""
    return {r["controller"]: r["Ep"] for r in results if r["group"] == "alone" and r["world"] == "ideal"}


def summary_rows(results: list[dict], controllers: list[str] | tuple[str, ...]) -> list[str]:
    """``| controller | runs | diverged | within | mean E_p | mean E_p / ideal |`` over the grid's runs."""
    ideal = ideal_ep(results)
    grid = [r for r in results if r["group"] == "grid"]
    lines = []
    for name in controllers:
        rows = [r for r in grid if r["controller"] == name]
        eps = [r["Ep"] for r in rows if r["Ep"] is not None and not r["diverged"]]
        mean = float(np.mean(eps)) if eps else math.nan
        lines.append(
            f"| {name} | {len(rows)} | {sum(r['diverged'] or bool(r['stopped']) for r in rows)} | "
            f"{sum(r['within_band'] for r in rows)} | {mean:.4f} | {mean / ideal[name]:.2f} |"
        )
    return lines


def _cell(r: dict | None, ideal: float | None, worst_error: bool = False) -> str:
    """One run's table cell: empty without a run, "diverged", else E_p (rad^2) and E_p / ``ideal``
    with " (out of band)" when out of the band; ``worst_error``: a * for out of the band and the
    worst joint error after 2 s (rad) instead."""
    if r is None:
        return ""
    if r["Ep"] is None or r["diverged"]:
        return "diverged"
    if worst_error:
        star = "" if r["within_band"] else "*"
        return f"{r['Ep']:.4f}{star} ({r['Ep'] / ideal:.2f}x, {r['max_error_after_2s']:.2f} rad)"
    band = "" if r["within_band"] else " (out of band)"
    return f"{r['Ep']:.4f} ({r['Ep'] / ideal:.2f}x){band}"


def table(results: list[dict], controllers: list[str] | tuple[str, ...] = tuple(CONTROLLERS)) -> str:
    ideal = ideal_ep(results)
    lines = ["| controller | runs | diverged | within 0.5 rad after 2 s | mean E_p (rad^2) | mean E_p / ideal |"]
    lines.append("|---|---|---|---|---|---|")
    lines += summary_rows(results, controllers)
    lines += ["", "| world | " + " | ".join(controllers) + " |", "|---|" + "---|" * len(controllers)]
    for group in ("alone", "grid-target", "target+", "control", "sensitivity"):
        worlds: dict[str, dict[str, dict]] = {}
        for r in results:
            is_target = r["group"] == "grid" and r["overrides"] == {
                "sensor.delay": 1,
                "friction.scale": 1.0,
                "sensor.dropout": 0.0,
            }
            if r["group"] == group or (group == "grid-target" and is_target):
                name = "target" if group == "grid-target" else r["world"]
                worlds.setdefault(name, {})[r["controller"]] = r
        for world, by in worlds.items():
            if not any(name in by for name in controllers):
                continue
            cells = [_cell(by.get(name), ideal.get(name)) for name in controllers]
            lines.append(f"| {world} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def grid_label(delay: int, scale: float, dropout: float) -> str:
    """A grid world's row label: ``1, 1x, 10 %``; the target world in bold."""
    label = f"{delay}, {f'{scale:g}x' if scale else '0'}, {f'{dropout * 100:g} %' if dropout else '0'}"
    return f"**{label} (target)**" if (delay, scale, dropout) == (1, 1.0, 0.0) else label


def grid_table(results: list[dict], controllers: list[str] | tuple[str, ...] = tuple(CONTROLLERS)) -> str:
    """The grid's worlds, one row each (sensor delay, friction, dropout), every controller's mean
    E_p (rad^2), ``*`` out of the band; docs/robustness.md prints it."""
    lines = ["| sensor delay, friction, dropout | " + " | ".join(controllers) + " |"]
    lines.append("|---|" + "---|" * len(controllers))
    worlds: dict[tuple, dict[str, dict]] = {}
    for r in results:
        if r["group"] == "grid":
            o = r["overrides"]
            key = (o["sensor.delay"], o["friction.scale"], o["sensor.dropout"])
            worlds.setdefault(key, {})[r["controller"]] = r
    for (delay, scale, dropout), by in sorted(worlds.items()):
        label = grid_label(delay, scale, dropout)
        cells = []
        for name in controllers:
            r = by[name]
            diverged = r["Ep"] is None or r["diverged"]
            cells.append("diverged" if diverged else f"{r['Ep']:.4f}{'' if r['within_band'] else '*'}")
        lines.append(f"| {label} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def arms_table(by_arm: dict[str, list[dict]], controllers: list[str] | tuple[str, ...]) -> str:
    """Per arm (``arm -> its runs``) and controller: the grid's runs, divergences, runs within
    the band, mean E_p (rad^2) and mean E_p / the arm's own ideal loop; docs/robustness.md prints it."""
    lines = [
        "| arm | controller | runs | diverged | within 0.5 rad after 2 s | mean E_p (rad^2) | mean E_p / ideal |",
        "|---|---|---|---|---|---|---|",
    ]
    for arm, runs in by_arm.items():
        lines += [f"| {arm} {row}" for row in summary_rows(runs, [c for c in controllers if _ran(runs, c)])]
    return "\n".join(lines)


def _ran(runs: list[dict], controller: str) -> bool:
    return any(r["group"] == "grid" and r["controller"] == controller for r in runs)


def arms_world_table(by_arm: dict[str, list[dict]], controller: str) -> str:
    """``controller``'s runs world by world (the grid, then each effect alone, then the target
    world's extras, as :func:`tasks` orders them; no world with a rate limit, left to the rate
    limit's own rows), one column per arm: E_p (rad^2), E_p / the arm's ideal loop, the worst
    joint error after 2 s (rad); ``*`` out of the band."""
    arms = list(by_arm)
    lines = ["| world | " + " | ".join(arms) + " |", "|---|" + "---|" * len(arms)]
    runs_of = enumerate(t for t in tasks("paper", [controller]) if t[0] in ("grid", "alone", "target+"))
    order = {(t[0], t[1]): k for k, t in runs_of}
    worlds: dict[tuple[str, str], dict[str, dict]] = {}
    for arm, runs in by_arm.items():
        for r in runs:
            rated = "actuator.rate_limit" in r["overrides"]
            if r["controller"] != controller or (r["group"], r["world"]) not in order or rated:
                continue
            worlds.setdefault((r["group"], r["world"]), {})[arm] = r
    ideals = {arm: ideal_ep(runs).get(controller) for arm, runs in by_arm.items()}
    for group, world in sorted(worlds, key=lambda key: (key[0] != "grid", order[key])):
        by = worlds[(group, world)]
        cells = [_cell(by.get(arm), ideals[arm], worst_error=True) for arm in arms]
        label = grid_label(*_grid_key(by)) if group == "grid" else world
        lines.append(f"| {label} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def arms_rate_table(by_arm: dict[str, list[dict]], controllers: list[str] | tuple[str, ...]) -> str:
    """The worlds with the drives' rate limit (those :func:`arms_world_table` leaves out), one row
    per arm and world, one column per controller: E_p (rad^2), E_p / the arm's ideal loop, the
    worst joint error after 2 s (rad); ``*`` out of the band. A run that ends far off without
    diverging (the runner's test: a non-finite state or a joint over 1000 rad/s) shows here."""
    lines = ["| arm | world | " + " | ".join(controllers) + " |", "|---|---|" + "---|" * len(controllers)]
    for arm, runs in by_arm.items():
        ideal = ideal_ep(runs)
        worlds: dict[str, dict[str, dict]] = {}
        for r in runs:
            if "actuator.rate_limit" in r["overrides"] and r["controller"] in controllers:
                worlds.setdefault(r["world"], {})[r["controller"]] = r
        for world, by in worlds.items():
            cells = [_cell(by.get(name), ideal.get(name), worst_error=True) for name in controllers]
            lines.append(f"| {arm} | {world} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def _grid_key(by: dict[str, dict]) -> tuple[int, float, float]:
    """(sensor delay, friction scale, dropout) of a grid world's runs."""
    o = next(iter(by.values()))["overrides"]
    return (o["sensor.delay"], o["friction.scale"], o["sensor.dropout"])


def reference_torque(arm: str) -> dict:
    """The torque the true plant (the arm's water and current, no joint friction) needs to follow
    ``arm``'s 10 s reference exactly, sampled every control period: per joint its peak (N m), the
    arm's torque limit (N m) and the share of the samples over the limit. The plant's acceleration
    is affine in the torque, ``a = A tau + b``: A and b from n + 1 evaluations, tau = A^-1 (a_r - b)."""
    target = arm_base(load_sweep(SWEEP).base, arm)
    config = ideal_base(target)
    experiment = build_experiment(config, "IDMPC")
    plant, reference = experiment.plant, experiment.reference
    n = reference.n_joints
    limit = np.broadcast_to(np.asarray(experiment.arm.torque_limit, dtype=float), (n,))
    times = np.arange(round(config.duration / config.control_period)) * config.control_period
    needed = np.empty((len(times), n))
    for k, t in enumerate(times):
        q, v, a = reference.sample(t)
        b = plant.acceleration(t, q, v, np.zeros(n))
        gain = np.column_stack([plant.acceleration(t, q, v, e) - b for e in np.eye(n)])
        needed[k] = np.linalg.solve(gain, a - b)
    over = np.abs(needed) > limit
    return {
        "peak_Nm": np.abs(needed).max(axis=0).tolist(),
        "limit_Nm": limit.tolist(),
        "share_over_limit": over.mean(axis=0).tolist(),
    }


def _select(args: argparse.Namespace) -> list[tuple]:
    todo = tasks(args.arm, args.controllers)
    if args.groups is not None:
        todo = [t for t in todo if t[0] in args.groups]
    if args.worlds is not None:
        todo = [t for t in todo if t[1] in args.worlds]
    if args.skip_worlds:
        todo = [t for t in todo if t[1] not in args.skip_worlds]
    if args.controllers is not None:
        todo = [t for t in todo if t[2] in args.controllers]
    return todo


def _merge_arm(path: Path, arm: str, todo: list[tuple], results: list[dict], wall: float, label: str) -> list[dict]:
    """Merge ``arm``'s new runs into the per-arm file at ``path`` (its other arms and runs kept)."""
    data = json.loads(path.read_text()) if path.exists() else {
        "sweep_file": "examples/real_loop.toml",
        "band_rad": BAND,
        "after_s": AFTER,
        "rate_limit_Nm_per_s": RATE_LIMIT,
        "bandwidth_Hz": BANDWIDTH,
        "friction": "the published per-joint values (Gaz et al. 2019's Panda, joint i for joint i) on every arm",
        "arms": {},
    }  # fmt: skip
    entry = data["arms"].setdefault(arm, {"arm": ARMS[arm], "runs": [], "wall_time_s": {}})
    done = {(t[0], t[1], t[2]) for t in todo}
    entry["runs"] = [r for r in entry["runs"] if (r["group"], r["world"], r["controller"]) not in done] + results
    entry["wall_time_s"][label] = wall
    entry["machine"] = {"cpus": os.cpu_count(), "python": platform.python_version()}
    _write_json(path, data)
    return entry["runs"]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--out", type=Path, default=None, help="default: docs/data/real_loop.json (paper arm)")
    parser.add_argument("--arm", choices=list(ARMS), default="paper", help="the arm whose task the worlds run on")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument(
        "--groups", nargs="*", default=None, help="run only these groups and merge them into --out (grid, alone, ...)"
    )
    parser.add_argument("--worlds", nargs="*", default=None, help="only these worlds")
    parser.add_argument("--skip-worlds", nargs="*", default=None, help="not these worlds")
    parser.add_argument(
        "--controllers", nargs="*", default=None, help="only these controllers (registry names or VARIANTS' labels)"
    )
    parser.add_argument(
        "--reference-torque",
        action="store_true",
        help="run nothing: store in --out the torque each arm's reference needs against its limits",
    )
    args = parser.parse_args()
    if args.out is None:
        if args.arm != "paper":
            parser.error("--arm other than paper: give --out (docs/data/real_loop_arms.json, keyed by arm)")
        args.out = Path("docs/data/real_loop.json")
    unknown = [c for c in args.controllers or [] if c not in CONTROLLERS and c not in VARIANTS]
    if unknown:
        parser.error(f"--controllers: unknown {unknown}; known: {list(CONTROLLERS) + list(VARIANTS)}")
    if args.reference_torque:
        data = json.loads(args.out.read_text())
        data["reference_torque"] = {arm: reference_torque(arm) for arm in ARMS}
        args.out.write_text(json.dumps(data, indent=1) + "\n")
        print(json.dumps(data["reference_torque"], indent=1))
        return
    todo = _select(args)
    start = time.perf_counter()
    label = ",".join((args.groups or ["all"]) + (args.worlds or []) + (args.controllers or []))
    merge = args.arm == "paper" and _merging(args) and args.out.exists()
    previous = json.loads(args.out.read_text()) if merge else None
    results = []
    with ProcessPoolExecutor(args.workers) as pool:
        for k, result in enumerate(pool.map(run, todo), 1):
            if args.arm != "paper":
                result["arm"] = args.arm
            results.append(result)
            print(f"[{k}/{len(todo)}] {result['group']} {result['world']} {result['controller']}: "
                  f"Ep={result['Ep']} within={result['within_band']}", flush=True)  # fmt: skip
            _save(args, previous, todo[:k], results, time.perf_counter() - start, label)  # an interrupt keeps these
    wall = time.perf_counter() - start
    runs = _save(args, previous, todo, results, wall, label)
    names = list(dict.fromkeys(r["controller"] for r in runs))
    if args.arm != "paper":
        print(arms_table({args.arm: runs}, names))
    elif previous is not None:
        print(table(runs, names))
    else:
        print(table(results))
        print(f"\n{len(results)} runs in {wall:.0f} s wall on {args.workers} workers -> {args.out}")


def _merging(args: argparse.Namespace) -> bool:
    """Whether the paper arm's run merges into ``--out`` (a part of the campaign: groups or controllers)."""
    return args.groups is not None or args.controllers is not None


def _save(args, previous: dict | None, done: list[tuple], results: list[dict], wall: float, label: str) -> list[dict]:
    """Write the runs finished so far into ``--out`` (after every run: an interrupted campaign keeps
    them) and return the file's runs for this arm: another arm's merge (:func:`_merge_arm`), the
    paper arm's merge into ``previous`` (its other runs kept, this part's wall time beside the
    first), or the whole campaign's file."""
    if args.arm != "paper":
        return _merge_arm(args.out, args.arm, done, results, wall, label)
    if previous is not None:
        keys = {(t[0], t[1], t[2]) for t in done}
        data = dict(previous)
        data["runs"] = [r for r in previous["runs"] if (r["group"], r["world"], r["controller"]) not in keys] + results
        data["extra_wall_time_s"] = {**previous.get("extra_wall_time_s", {}), label: wall}
    else:
        data = {
            "sweep_file": "examples/real_loop.toml",
            "band_rad": BAND,
            "after_s": AFTER,
            "rate_limit_Nm_per_s": RATE_LIMIT,
            "bandwidth_Hz": BANDWIDTH,
            "workers": args.workers,
            "wall_time_s": wall,
            "cpu_time_s": sum(r["wall_s"] for r in results),
            "machine": {"cpus": os.cpu_count(), "python": platform.python_version()},
            "runs": results,
        }
    _write_json(args.out, data)
    return data["runs"]


def _write_json(path: Path, data: dict) -> None:
    """Write ``data`` to ``path`` whole or not at all (a temporary file renamed over it)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    partial = path.with_suffix(path.suffix + ".partial")
    partial.write_text(json.dumps(data, indent=1) + "\n")
    partial.replace(path)


if __name__ == "__main__":
    main()
