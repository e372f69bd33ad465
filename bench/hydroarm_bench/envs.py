"""The Gymnasium environment's speed: environment steps per second of one ``UnderwaterArm-v0``
(``gymnasium.make``) and of an 8-copy vector environment (``gymnasium.make_vec``: the id's
``vector_entry_point``, :class:`hydroarm.envs.vector.WorkerVectorEnv`, one lane per core), random
normalised actions, in the same process, interleaved: each repeat times the single env, then the
vector env, over the same number of environment steps; the medians over the repeats and the
median of the repeats' ratios are reported. Gymnasium's own ``"async"`` vector env (one process
per copy) is timed once beside them for reference (not in ``--quick``).

An environment step of the vector env is one copy's step (the autoreset steps of ``NEXT_STEP``,
which only reset, are not counted, as in ``gymnasium.utils.performance.benchmark_vector_step``).
The compile cost and the workers' start are paid at make (timed apart). The machine's load
average at the start and the end, the CPU time per environment step (this process plus the
workers, Linux) and the cores each kept busy say how much the wall-clock ratio owes to a busy
machine: where other sessions keep the cores busy, Linux shares the cores out per session
(autogroups), and the vector env's lanes together get no more than the single env's session does.
"""

from __future__ import annotations

import os
import time

import numpy as np

COPIES = 8
ENV_ID = "hydroarm.envs:hydroarm/UnderwaterArm-v0"


def _cpu_seconds(pids: list[int]) -> float:
    """CPU time (user + system, s) of this process and of the processes ``pids`` (Linux /proc;
    NaN elsewhere)."""
    total = time.process_time()
    try:
        ticks = os.sysconf("SC_CLK_TCK")
        for pid in pids:
            with open(f"/proc/{pid}/stat") as stat:
                fields = stat.read().rsplit(")", 1)[1].split()
            total += (int(fields[11]) + int(fields[12])) / ticks
    except (OSError, ValueError, AttributeError):
        return float("nan")
    return total


def _cpu_model() -> str:
    """The CPU's model name (Linux /proc/cpuinfo), or the platform's processor string."""
    import platform

    try:
        with open("/proc/cpuinfo") as info:
            for line in info:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown CPU"


def _single_rate(env, actions: np.ndarray) -> tuple[float, float]:
    """(environment steps / s, CPU s per step) of ``env`` over the rows of ``actions``."""
    cpu, started = _cpu_seconds([]), time.perf_counter()
    for action in actions:
        _, _, terminated, truncated, _ = env.step(action)
        if terminated or truncated:
            env.reset()
    wall, cpu = time.perf_counter() - started, _cpu_seconds([]) - cpu
    return len(actions) / wall, cpu / len(actions)


def _vector_rate(envs, actions: np.ndarray, pids: list[int]) -> tuple[float, float]:
    """(environment steps / s, CPU s per environment step, workers included) of the vector env
    ``envs`` over the batches of ``actions``."""
    steps, done = 0, np.zeros(envs.num_envs, dtype=bool)
    cpu, started = _cpu_seconds(pids), time.perf_counter()
    for batch in actions:
        _, _, terminated, truncated, _ = envs.step(batch)
        steps += envs.num_envs - int(np.count_nonzero(done))
        done = terminated | truncated
    wall, cpu = time.perf_counter() - started, _cpu_seconds(pids) - cpu
    return steps / wall, cpu / steps


def _async_rate(gymnasium, arm: str, actions: np.ndarray) -> float:
    """Environment steps / s of Gymnasium's ``AsyncVectorEnv`` (one process per copy)."""
    envs = gymnasium.make_vec(ENV_ID, num_envs=COPIES, vectorization_mode="async", arm=arm)
    try:
        envs.reset(seed=0)
        envs.step(actions[0])
        rate, _ = _vector_rate(envs, actions, [])
    finally:
        envs.close()
    return rate


def bench_envs(quick: bool, arm: str = "alpha5") -> dict:
    """``single_steps_per_s`` and ``vector_env_steps_per_s`` (medians over the repeats),
    ``speedup`` (their ratio) and ``speedup_per_repeat``, the CPU time per environment step of
    each, the make times (s), the lanes, and the load average at the start and the end."""
    try:
        import gymnasium
    except ImportError as error:
        return {"skipped": f"{error.name} is missing (pip install -e '.[gym]')"}
    from hydroarm.envs.vector import default_workers

    repeats, steps = (3, 400) if quick else (7, 1600)
    load_start = os.getloadavg()
    started = time.perf_counter()
    env = gymnasium.make(ENV_ID, arm=arm)
    single_make = time.perf_counter() - started
    started = time.perf_counter()
    envs = gymnasium.make_vec(ENV_ID, num_envs=COPIES, arm=arm)
    vector_make = time.perf_counter() - started
    try:
        inner = envs.unwrapped
        pids = list(inner.worker_pids)
        env.reset(seed=0)
        envs.reset(seed=0)
        rng = np.random.default_rng(0)
        shape = envs.action_space.shape
        singles, vectors, single_cpu, vector_cpu = [], [], [], []
        for _ in range(repeats):
            rate, cpu = _single_rate(env, rng.uniform(-1.0, 1.0, (steps, shape[1])))
            singles.append(rate)
            single_cpu.append(cpu)
            rate, cpu = _vector_rate(envs, rng.uniform(-1.0, 1.0, (steps // COPIES, *shape)), pids)
            vectors.append(rate)
            vector_cpu.append(cpu)
        workers, autoreset = inner.workers, inner.metadata["autoreset_mode"].value
    finally:
        env.close()
        envs.close()
    single, vector = float(np.median(singles)), float(np.median(vectors))
    section = {
        "arm": arm,
        "copies": COPIES,
        "vector_env": "WorkerVectorEnv (gymnasium.make_vec, the vector_entry_point)",
        "workers": workers,
        "autoreset_mode": autoreset,
        "repeats": repeats,
        "steps_per_repeat": steps,
        "single_steps_per_s": single,
        "vector_env_steps_per_s": vector,
        "speedup": vector / single,
        "speedup_per_repeat": [v / s for v, s in zip(vectors, singles, strict=True)],
        "single_steps_per_s_all": singles,
        "vector_env_steps_per_s_all": vectors,
        "single_cpu_ms_per_step": 1e3 * float(np.median(single_cpu)),
        "vector_cpu_ms_per_env_step": 1e3 * float(np.median(vector_cpu)),
        # cores kept busy (CPU s per wall s): on a shared machine the vector env's lanes get no
        # more than this session's fair share of the cores (Linux autogroups share them out per
        # session), which a single env may already use most of
        "single_cores_used": float(np.median(np.array(singles) * np.array(single_cpu))),
        "vector_cores_used": float(np.median(np.array(vectors) * np.array(vector_cpu))),
        "single_make_s": single_make,
        "vector_make_s": vector_make,
        "cpus": os.cpu_count(),
        "cores_available": default_workers(),
        "load_average_start": [round(x, 2) for x in load_start],
        "load_average_end": [round(x, 2) for x in os.getloadavg()],
    }
    if not quick:
        actions = np.random.default_rng(1).uniform(-1.0, 1.0, (steps // COPIES, *shape))
        section["async_env_steps_per_s"] = _async_rate(gymnasium, arm, actions)
        section["async_speedup"] = section["async_env_steps_per_s"] / single
    return section


def render_envs(section: dict) -> str:
    """The environment's section of bench.md."""
    if "skipped" in section:
        return f"\n## Gymnasium environment\n\nSkipped: {section['skipped']}\n"
    reference = ""
    if "async_env_steps_per_s" in section:
        reference = (
            f" Gymnasium's async vector env (one process per copy) gave {section['async_env_steps_per_s']:.0f} "
            f"environment steps/s ({section['async_speedup']:.2f}x), timed once."
        )
    return (
        "\n## Gymnasium environment\n\n"
        f"`UnderwaterArm-v0` on {section['arm']}, random normalised actions, medians of {section['repeats']} "
        f"interleaved repeats: one environment {section['single_steps_per_s']:.0f} steps/s; the "
        f"{section['copies']}-copy vector environment of `gymnasium.make_vec` ({section['workers']} lanes) "
        f"{section['vector_env_steps_per_s']:.0f} environment steps/s (**{section['speedup']:.2f}x**; per repeat "
        + ", ".join(f"{x:.2f}" for x in section["speedup_per_repeat"])
        + f") on {section['cores_available']} cores, load average {section['load_average_start'][0]:.1f} at the "
        f"start and {section['load_average_end'][0]:.1f} at the end. CPU time per environment step: "
        f"{section['single_cpu_ms_per_step']:.3f} ms single, {section['vector_cpu_ms_per_env_step']:.3f} ms in the "
        f"vector env (workers included); cores kept busy: {section['single_cores_used']:.2f} single, "
        f"{section['vector_cores_used']:.2f} vector. Made in {section['single_make_s']:.1f} s and "
        f"{section['vector_make_s']:.1f} s (the compiled step and the workers' start are paid there).{reference}\n"
    )


def main(argv: list[str] | None = None) -> int:
    """``python -m hydroarm_bench.envs --out FILE [--quick]`` (with ``bench/`` on ``PYTHONPATH``):
    this section alone, as JSON with the date, the machine and its load (``hydroarm bench`` runs
    it inside the whole suite)."""
    import argparse
    import json
    import platform
    import sys
    from datetime import UTC, datetime
    from pathlib import Path

    parser = argparse.ArgumentParser(prog="hydroarm_bench.envs", description="Time the vector env against one env.")
    parser.add_argument("--out", type=Path, required=True, help="the JSON file to write")
    parser.add_argument("--quick", action="store_true", help="fewer repeats and steps")
    args = parser.parse_args(argv)
    section = bench_envs(args.quick)
    section["date"] = datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC")
    section["machine"] = f"{platform.machine()}, {_cpu_model()}, {os.cpu_count()} CPUs"
    section["python"] = sys.version.split()[0]
    args.out.write_text(json.dumps(section, indent=1) + "\n")
    print(render_envs(section))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
