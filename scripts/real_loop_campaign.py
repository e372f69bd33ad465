"""The real-loop campaign (issue 23): which controller survives encoders, delay, friction, limits?

Runs every controller on the paper task (10 s, Table 1's noise-free sensor otherwise) in

* the grid of ``examples/real_loop.toml`` (the sweep file is the one source of the grid and its
  base, the target world: a 16-bit encoder measuring position only, one period of loop delay,
  the published joint friction; around it sensor delay 0-2, friction 0-2x, dropout 0/10 %), and
* each effect on its own, from the ideal loop (:data:`EFFECTS`), plus the target world with the
  drives' rate limit and bandwidth, and two flagship-only controls (no delay prediction; the
  filter's default sigma_a^2).

Every run is on default settings (issue 32: no hand-set filter): ``estimator.kind = "auto"`` puts
every controller behind the Kalman filter wherever the sensor is not the ideal one or the loop has
a delay, with sigma_a^2 derived from the sensor; on the ideal sensor that filter passes the
measurement through, so the ideal loop's numbers are the reproduction's. Per run: diverged,
within the band (ran to the end and |q_r - q| < 0.5 rad on every joint from 2 s on), E_p (mean
over joints and samples, rad^2), and E_p relative to the same controller's ideal loop. Writes
``--out`` (JSON) and prints the tables.

Usage: python scripts/real_loop_campaign.py [--out docs/data/real_loop.json] [--workers 2]
"""

from __future__ import annotations

import argparse
import json
import math
import platform
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from hydroarm.control.registry import CONTROLLERS
from hydroarm.sim.experiment import ExperimentConfig, build_experiment, with_overrides
from hydroarm.studies.sweep.plan import plan_sweep
from hydroarm.studies.sweep.schema import load_sweep

SWEEP = Path(__file__).resolve().parents[1] / "examples" / "real_loop.toml"
BAND, AFTER = 0.5, 2.0  # rad, s: the stress study's bound
FLAGSHIP = "GP-IDMPC"
SIXTEEN_BIT = 2 * math.pi / 2**16
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


def ideal_base(target: ExperimentConfig) -> ExperimentConfig:
    """The ideal loop: every real-loop setting at its default (the target's filter settings, its defaults too)."""
    return ExperimentConfig(arm=target.arm, duration=target.duration, estimator=target.estimator)


def run(task: tuple[str, str, str, dict, dict, int]) -> dict:
    """One run: ``(group, world, controller, base settings (JSON), overrides, seed)``."""
    group, world, controller, base, overrides, seed = task
    config = with_overrides(ExperimentConfig.model_validate(base), overrides)
    experiment = build_experiment(config, controller)
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
        "inner_step_s": experiment.plant.inner_step,
        "dropped": (traj.meta.get("sensor") or {}).get("dropped", 0),
        "wall_s": wall,
    }


def tasks() -> list[tuple]:
    sweep = load_sweep(SWEEP)
    plan = plan_sweep(sweep, SWEEP.parent)
    target = sweep.base
    ideal = ideal_base(target).model_dump(mode="json")
    target_json = target.model_dump(mode="json")
    out: list[tuple] = []
    for row in plan.rows:
        world = ", ".join(f"{k.split('.')[-1]}={v:g}" for k, v in row.params.items())
        out.append(("grid", world, row.controller, target_json, dict(row.params), row.seed))
    for world, overrides in EFFECTS.items():
        out += [("alone", world, name, ideal, overrides, 0) for name in CONTROLLERS]
    for world, overrides in TARGET_EXTRA.items():
        out += [("target+", world, name, target_json, overrides, 0) for name in CONTROLLERS]
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


def table(results: list[dict]) -> str:
    ideal = {r["controller"]: r["Ep"] for r in results if r["group"] == "alone" and r["world"] == "ideal"}
    lines = ["| controller | runs | diverged | within 0.5 rad after 2 s | mean E_p (rad^2) | mean E_p / ideal |"]
    lines.append("|---|---|---|---|---|---|")
    grid = [r for r in results if r["group"] == "grid"]
    for name in CONTROLLERS:
        rows = [r for r in grid if r["controller"] == name]
        eps = [r["Ep"] for r in rows if r["Ep"] is not None and not r["diverged"]]
        mean = float(np.mean(eps)) if eps else math.nan
        lines.append(
            f"| {name} | {len(rows)} | {sum(r['diverged'] or bool(r['stopped']) for r in rows)} | "
            f"{sum(r['within_band'] for r in rows)} | {mean:.4f} | {mean / ideal[name]:.2f} |"
        )
    lines += ["", "| world | " + " | ".join(CONTROLLERS) + " |", "|---|" + "---|" * len(CONTROLLERS)]
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
            cells = []
            for name in CONTROLLERS:
                r = by.get(name)
                if r is None:
                    cells.append("")
                elif r["Ep"] is None or r["diverged"]:
                    cells.append("diverged")
                else:
                    band = "" if r["within_band"] else " (out of band)"
                    cells.append(f"{r['Ep']:.4f} ({r['Ep'] / ideal[name]:.2f}x){band}")
            lines.append(f"| {world} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def grid_table(results: list[dict]) -> str:
    """The grid's worlds, one row each (sensor delay, friction, dropout), every controller's mean
    E_p (rad^2), ``*`` out of the band; docs/robustness.md prints it."""
    lines = ["| sensor delay, friction, dropout | " + " | ".join(CONTROLLERS) + " |"]
    lines.append("|---|" + "---|" * len(CONTROLLERS))
    worlds: dict[tuple, dict[str, dict]] = {}
    for r in results:
        if r["group"] == "grid":
            o = r["overrides"]
            key = (o["sensor.delay"], o["friction.scale"], o["sensor.dropout"])
            worlds.setdefault(key, {})[r["controller"]] = r
    for (delay, scale, dropout), by in sorted(worlds.items()):
        label = f"{delay}, {f'{scale:g}x' if scale else '0'}, {f'{dropout * 100:g} %' if dropout else '0'}"
        if (delay, scale, dropout) == (1, 1.0, 0.0):
            label = f"**{label} (target)**"
        cells = []
        for name in CONTROLLERS:
            r = by[name]
            diverged = r["Ep"] is None or r["diverged"]
            cells.append("diverged" if diverged else f"{r['Ep']:.4f}{'' if r['within_band'] else '*'}")
        lines.append(f"| {label} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--out", type=Path, default=Path("docs/data/real_loop.json"))
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument(
        "--groups", nargs="*", default=None, help="run only these groups and merge them into --out (grid, alone, ...)"
    )
    parser.add_argument("--worlds", nargs="*", default=None, help="with --groups: only these worlds of them")
    parser.add_argument("--controllers", nargs="*", default=None, help="with --groups: only these controllers")
    args = parser.parse_args()
    todo = tasks() if args.groups is None else [t for t in tasks() if t[0] in args.groups]
    if args.worlds is not None:
        todo = [t for t in todo if t[1] in args.worlds]
    if args.controllers is not None:
        todo = [t for t in todo if t[2] in args.controllers]
    start = time.perf_counter()
    results = []
    with ProcessPoolExecutor(args.workers) as pool:
        for k, result in enumerate(pool.map(run, todo), 1):
            results.append(result)
            print(f"[{k}/{len(todo)}] {result['group']} {result['world']} {result['controller']}: "
                  f"Ep={result['Ep']} within={result['within_band']}", flush=True)  # fmt: skip
    wall = time.perf_counter() - start
    if args.groups is not None:  # merge: keep the other groups' runs and the first wall time
        previous = json.loads(args.out.read_text())
        done = {(t[0], t[1], t[2]) for t in todo}
        kept = [r for r in previous["runs"] if (r["group"], r["world"], r["controller"]) not in done]
        previous["runs"] = kept + results
        label = ",".join(args.groups + (args.worlds or []) + (args.controllers or []))
        previous.setdefault("extra_wall_time_s", {})[label] = wall
        args.out.write_text(json.dumps(previous, indent=1) + "\n")
        print(table(previous["runs"]))
        return
    payload = {
        "sweep_file": "examples/real_loop.toml",
        "band_rad": BAND,
        "after_s": AFTER,
        "rate_limit_Nm_per_s": RATE_LIMIT,
        "bandwidth_Hz": BANDWIDTH,
        "workers": args.workers,
        "wall_time_s": wall,
        "cpu_time_s": sum(r["wall_s"] for r in results),
        "machine": {"cpus": __import__("os").cpu_count(), "python": platform.python_version()},
        "runs": results,
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(payload, indent=1) + "\n")
    print(table(results))
    print(f"\n{len(results)} runs in {wall:.0f} s wall on {args.workers} workers -> {args.out}")


if __name__ == "__main__":
    main()
