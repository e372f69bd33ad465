"""The batched arm plant on JAX (a GPU when there is one): checked against numba, then timed.

Two modes (docs/model.md, "A GPU path"):

``--export FILE.npz`` (here, with hydroarm): the compiled plant's constants
(:func:`hydroarm.model.arm.fast_export.export_constants`), a few seeded copies' initial states and
held torques, their start times (0.37 s apart: the paper current's phase differs per copy), the numba
:class:`~hydroarm.model.arm.fast.BatchedArm`'s results after 1 and after ``--periods`` control
periods of 10 ms, and the numba batched rate measured in the same run
(copy-steps/s, this machine's cores).

``--run FILE.npz --copies 1024 16384 131072 --steps N --out result.json`` (anywhere with JAX and
NumPy only: :mod:`hydroarm.model.arm.fast_jax` is loaded by file path): the JAX period against the
file's numba reference (max relative difference per copy, max over copies), then per count of
copies the compile time, the wall time of ``--steps`` periods (warm-up excluded,
``block_until_ready``), copy-steps/s and the ratio to the file's numba rate; the device and the
JAX version. The JSON is rewritten after every count (an interrupted run keeps what finished);
counts that would start after ``--budget-s`` seconds are listed as skipped.

    python scripts/gpu_plant.py --export bench/gpu/paper.npz --arm paper
    python scripts/gpu_plant.py --export f.npz --arm my.toml --set friction.scale=1 --set plant.friction=0.3
    python3 scripts/gpu_plant.py --run bench/gpu/paper.npz --copies 1024 16384 131072 --steps 20 --out r.json
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import platform
import sys
import time
from pathlib import Path

import numpy as np

PERIOD = 0.01
ARM_JAX = Path(__file__).resolve().parents[1] / "src" / "hydroarm" / "model" / "arm" / "fast_jax.py"


def _copies(x_base, limit, count, seed):
    """Seeded copies: the start moved by U(-0.1, 0.1) (rad, rad/s), torques U(-0.1, 0.1) x the limits."""
    rng = np.random.default_rng(seed)
    x = x_base + rng.uniform(-0.1, 0.1, (count, x_base.size))
    tau = 0.1 * limit * rng.uniform(-1.0, 1.0, (count, limit.size))
    return x, tau


def export(path: Path, arm: str, copies: int, periods: int, drag_points: int | None, seed: int,
           settings: dict | None = None) -> dict:  # fmt: skip
    """Write the file of ``--export`` (module docstring), the plant of ``arm`` with the dotted
    ``settings`` (``--set``) on top; returns its metadata."""
    import datetime

    import numba

    from hydroarm.model.arm.fast import BatchedArm
    from hydroarm.model.arm.fast_export import export_constants
    from hydroarm.model.dynamics.integrator import inner_steps
    from hydroarm.sim.experiment import ExperimentConfig, build_experiment, with_overrides

    overrides = {**(settings or {}), "arm": arm, "plant.compiled": True}
    if drag_points is not None:
        overrides["plant.drag_points"] = drag_points
    experiment = build_experiment(with_overrides(ExperimentConfig(), overrides), None)
    plant = experiment.plant
    x_base = np.asarray(experiment.x0, dtype=float)
    limit = np.asarray(experiment.arm.torque_limit, dtype=float)
    x, tau = _copies(x_base, limit, copies, seed)
    batch = BatchedArm(plant.fast)
    t0 = 0.37 * np.arange(copies)
    first = batch.step(t0, x, tau, PERIOD, plant.inner_step)
    state = first[0]
    for k in range(1, periods):
        state = batch.step(t0 + k * PERIOD, state, tau, PERIOD, plant.inner_step)[0]
    big_x, big_tau = _copies(x_base, limit, 512, seed + 1)  # the numba rate, 512 copies, every core
    batch.step(0.0, big_x, big_tau, PERIOD, plant.inner_step)
    wall, rate_steps = time.perf_counter(), 20
    for k in range(rate_steps):
        big_x = batch.step(k * PERIOD, big_x, big_tau, PERIOD, plant.inner_step)[0]
    wall = time.perf_counter() - wall
    steps, h = inner_steps(PERIOD, plant.inner_step)
    meta = {
        "arm": arm, "settings": settings or {}, "copies": copies, "periods": periods, "seed": seed,
        "period_s": PERIOD, "inner_steps": steps,
        "h_s": h, "drag_points": int(export_constants(plant.fast)["nodes"].size),
        "numba_copy_steps_per_s": 512 * rate_steps / wall, "numba_threads": int(numba.get_num_threads()),
        "numba_machine": f"{platform.processor() or platform.machine()}, {numba.config.NUMBA_NUM_THREADS} cores",
        "exported": datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%d %H:%M UTC"),
    }  # fmt: skip
    arrays = {f"c_{k}": v for k, v in export_constants(plant.fast).items()}
    arrays.update(x0=x, tau=tau, t0=t0, x_base=x_base, torque_limit=limit, ref1_x=first[0], ref1_dist=first[1],
                  ref1_start=first[2], refk_x=state, meta=np.array(json.dumps(meta)))  # fmt: skip
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(path, **arrays)
    return meta


def _relative(a, b) -> float:
    """max over copies of max |a - b| / max |b| (per copy)."""
    a, b = np.asarray(a), np.asarray(b)
    return float(np.max(np.max(np.abs(a - b), axis=1) / np.maximum(np.max(np.abs(b), axis=1), 1e-300)))


def _blocked_periods(period, state, tau, count: int, start: int, periods: int) -> dict:
    """``periods`` more periods, each waited for (``block_until_ready``): min, median, max (s)."""
    times = []
    for j in range(start, start + periods):
        begin = time.perf_counter()
        state = period(np.full(count, j * PERIOD), state, tau)[0]
        state.block_until_ready()
        times.append(time.perf_counter() - begin)
    return {"periods": periods, "min": min(times), "median": float(np.median(times)), "max": max(times)}


def _load_arm_jax():
    spec = importlib.util.spec_from_file_location("arm_jax", ARM_JAX)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def run(path: Path, counts: list[int], steps: int, out: Path | None, budget: float, copy_seed: int | None = None,
        blocked: int = 0) -> dict:  # fmt: skip
    """``--run`` (module docstring): the check, then the timing per count; returns the result.
    ``copy_seed``: the seed of the timed copies (None: the file's seed + 2); ``blocked``: that many
    more periods timed one by one (each waited for), their min, median and max in the row (s)."""
    begin = time.perf_counter()
    arm_jax = _load_arm_jax()
    data = np.load(path, allow_pickle=False)
    meta = json.loads(str(data["meta"]))
    constants = {k[2:]: data[k] for k in data.files if k.startswith("c_")}
    seed = meta["seed"] + 2 if copy_seed is None else copy_seed
    period = arm_jax.make_period(constants, meta["inner_steps"], meta["h_s"])
    import jax

    result = {"file": str(path), "arm": meta["arm"], "jax": jax.__version__, "device": str(jax.devices()[0]),
              "device_kind": jax.devices()[0].device_kind, "platform": jax.default_backend(), "steps": steps,
              "numba": {k: meta[k] for k in ("numba_copy_steps_per_s", "numba_threads", "numba_machine", "exported")},
              "rows": [], "skipped": []}  # fmt: skip

    def save():
        if out is not None:
            out.parent.mkdir(parents=True, exist_ok=True)
            out.write_text(json.dumps(result, indent=2) + "\n")

    x0, tau0 = data["x0"], data["tau"]
    ref = x0.shape[0]
    for number, count in enumerate(counts):
        if time.perf_counter() - begin > budget:
            result["skipped"].append(count)
            save()
            continue
        x, tau = _copies(data["x_base"], data["torque_limit"], count, seed)
        t0 = np.zeros(count)
        if number == 0:  # the check rides on the first count's compile
            k = min(ref, count)
            x[:k], tau[:k] = x0[:k], tau0[:k]
            t0[:k] = data["t0"][:k] if "t0" in data.files else 0.0  # files exported before t0: all at 0
        tau = jax.device_put(tau)
        compile_s = time.perf_counter()
        state, dist, start = period(t0, x, tau)
        state.block_until_ready()
        compile_s = time.perf_counter() - compile_s
        if number == 0:
            after_1 = {"state": _relative(state[:k], data["ref1_x"][:k]),
                       "disturbance": _relative(dist[:k], data["ref1_dist"][:k]),
                       "first_stage_disturbance": _relative(start[:k], data["ref1_start"][:k])}  # fmt: skip
            check = {"copies": k, "periods": meta["periods"], "after_1": after_1}
            s = state
            for j in range(1, meta["periods"]):
                s = period(t0 + j * PERIOD, s, tau)[0]
            check["after_periods"] = {"state": _relative(np.asarray(s)[:k], data["refk_x"][:k])}
            result["check"] = check
            print(json.dumps({"check": check, "compile_s": compile_s}), file=sys.stderr, flush=True)
            save()
        wall = time.perf_counter()
        for j in range(steps):
            state = period(np.full(count, j * PERIOD), state, tau)[0]
        state.block_until_ready()
        wall = time.perf_counter() - wall
        rate = count * steps / wall
        result["rows"].append({"copies": count, "compile_s": compile_s, "wall_s": wall, "copy_steps_per_s": rate,
                               "ratio_to_numba": rate / meta["numba_copy_steps_per_s"],
                               "finite": bool(np.all(np.isfinite(np.asarray(state)))),
                               "copy_seed": seed})  # fmt: skip
        if blocked:
            result["rows"][-1]["blocked_period_s"] = _blocked_periods(period, state, tau, count, steps, blocked)
        print(json.dumps(result["rows"][-1]), file=sys.stderr, flush=True)
        save()
    result["total_s"] = time.perf_counter() - begin
    save()
    return result


def _setting(parser: argparse.ArgumentParser, text: str) -> tuple[str, object]:
    """``KEY=VALUE`` of ``--set``: the value as JSON where it parses (numbers, true, lists), else text."""
    key, sep, value = text.partition("=")
    if not sep or not key:
        parser.error(f"--set {text}: expected KEY=VALUE")
    try:
        return key, json.loads(value)
    except json.JSONDecodeError:
        return key, value


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    mode = parser.add_mutually_exclusive_group(required=True)
    mode.add_argument("--export", type=Path, metavar="FILE.npz")
    mode.add_argument("--run", type=Path, metavar="FILE.npz")
    parser.add_argument("--arm", default="paper")
    parser.add_argument("--reference-copies", type=int, default=4)
    parser.add_argument("--periods", type=int, default=20)
    parser.add_argument("--drag-points", type=int, default=None)
    parser.add_argument("--set", dest="settings", action="append", default=[], metavar="KEY=VALUE",
                        help="--export: a setting of the plant (hydroarm run's --set), repeatable")  # fmt: skip
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--copies", type=int, nargs="+", default=[1024, 16384, 131072])
    parser.add_argument("--steps", type=int, default=20)
    parser.add_argument("--budget-s", type=float, default=180.0)
    parser.add_argument("--out", type=Path, default=None)
    parser.add_argument("--copy-seed", type=int, default=None, help="--run: the timed copies' seed (file's + 2)")
    parser.add_argument("--blocked", type=int, default=0, help="--run: periods more, timed one by one")
    args = parser.parse_args(argv)
    if min(args.steps, args.periods, args.reference_copies, *args.copies) < 1:
        parser.error("--steps, --periods, --reference-copies and every --copies must be >= 1")
    if args.export is not None:
        settings = dict(_setting(parser, text) for text in args.settings)
        meta = export(args.export, args.arm, args.reference_copies, args.periods, args.drag_points, args.seed,
                      settings)  # fmt: skip
        print(json.dumps(meta, indent=2))
        return 0
    if not args.run.is_file():
        parser.error(f"--run {args.run}: no such file")
    result = run(args.run, args.copies, args.steps, args.out, args.budget_s, args.copy_seed, args.blocked)
    print(json.dumps(result, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
