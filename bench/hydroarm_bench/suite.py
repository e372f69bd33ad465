"""The driver: every section in order, then bench.json and bench.md."""

from __future__ import annotations

import json
import os
import time
from datetime import UTC, datetime
from pathlib import Path

from hydroarm_bench.arm_fast import bench_arm_fast, render_arm_fast
from hydroarm_bench.batched_env import bench_batched_env, render_batched_env
from hydroarm_bench.control_steps import bench_control_steps
from hydroarm_bench.envs import bench_envs, render_envs
from hydroarm_bench.flagship import bench_flagship, render_flagship
from hydroarm_bench.gp_peers import bench_gp_peers, record_gp_stream
from hydroarm_bench.markdown import render_markdown
from hydroarm_bench.mpc_peers import bench_mpc_peers
from hydroarm_bench.planner import bench_planner, render_planner
from hydroarm_bench.plant import bench_plant
from hydroarm_bench.profiling import profile_closed_loop
from hydroarm_bench.replay import bench_replay, render_replay
from hydroarm_bench.report import _machine, assemble, json_default, target_status
from hydroarm_bench.scaling import bench_scaling
from hydroarm_bench.stats import limit_threads
from hydroarm_bench.uvms import bench_uvms, render_uvms
from hydroarm_bench.viewer import bench_viewer, render_viewer


def run_benchmarks(out_dir: Path, quick: bool = False) -> dict:
    """Run the suite; write ``out_dir/bench.json`` and ``out_dir/bench.md``; return the JSON document."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    limiter, blas_threads, how = limit_threads()
    started = time.perf_counter()
    load_start = os.getloadavg()
    seconds: dict[str, float] = {}

    def timed(name, bench, *args):
        start = time.perf_counter()
        try:
            return bench(*args)
        finally:
            seconds[name] = time.perf_counter() - start

    try:
        breakdown, throughput, recorded = timed("control_steps", bench_control_steps, quick)
        events = timed("gp_stream", record_gp_stream, 4.0 if quick else 13.0)  # 13 s: >= 1000 full windows of 200
        mpc_peers = timed("mpc_peers", bench_mpc_peers, recorded, breakdown["MPC"]["total"], quick)
        gp_peers = timed("gp_peers", bench_gp_peers, events, quick)
        plant = timed("plant", bench_plant, recorded, quick)
        arm_fast = timed("arm_fast", bench_arm_fast, quick)
        batched_env = timed("batched_env", bench_batched_env, quick)
        scaling = timed("scaling", bench_scaling, events, recorded, quick)
        profile = timed("profile", profile_closed_loop, 1.0 if quick else 3.0)
        uvms = timed("uvms", bench_uvms, quick)
        viewer = timed("viewer", bench_viewer, quick)
        envs = timed("envs", bench_envs, quick)
        replay = timed("replay", bench_replay, quick)
        planner = timed("planner", bench_planner, quick)
    finally:
        if limiter is not None:
            limiter.unregister()
    report = assemble(quick, blas_threads, how, load_start, breakdown, throughput, mpc_peers, gp_peers, plant, scaling)
    report["profile"] = profile
    report["arm_fast"] = arm_fast
    report["batched_env"] = batched_env
    report["uvms"] = uvms
    report["viewer"] = viewer
    report["envs"] = envs
    report["replay"] = replay
    report["planner"] = planner
    report["target_status"] = target_status(report)  # again, with the vehicle and viewer sections
    report["suite_wall_s"] = time.perf_counter() - started
    report["section_wall_s"] = seconds  # where the suite's time goes, per section (s)
    report = json.loads(json.dumps(report, default=json_default))  # plain JSON types only
    (out_dir / "bench.json").write_text(json.dumps(report, indent=2) + "\n")
    (out_dir / "bench.md").write_text(
        render_markdown(report)
        + render_arm_fast(report["arm_fast"])
        + render_batched_env(report["batched_env"])
        + render_uvms(report["uvms"])
        + render_viewer(report["viewer"])
        + render_envs(envs)
        + render_replay(report["replay"])
        + render_planner(report["planner"])
    )
    return report


SECTIONS = {
    "arm_fast": (bench_arm_fast, render_arm_fast),
    "batched_env": (bench_batched_env, render_batched_env),
    "flagship": (bench_flagship, render_flagship),
    "planner": (bench_planner, render_planner),
    "uvms": (bench_uvms, render_uvms),
}
"""The sections ``--only`` runs alone (their own files, bench.json untouched)."""


def run_section(out_dir: Path, name: str, quick: bool = False) -> dict:
    """Run one section of :data:`SECTIONS`; write ``out_dir/bench-NAME.json`` and ``.md``."""
    bench, render = SECTIONS[name]
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    limiter, blas_threads, how = limit_threads()
    load_start = os.getloadavg()
    try:
        section = bench(quick)
    finally:
        if limiter is not None:
            limiter.unregister()
    report = {
        "quick": quick,
        "date": datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC"),
        "machine": _machine(load_start),
        "blas_threads": blas_threads,
        "blas_threads_set_by": how,
        "load_average": [load_start, os.getloadavg()],
        name: section,
    }
    report = json.loads(json.dumps(report, default=json_default))
    (out_dir / f"bench-{name}.json").write_text(json.dumps(report, indent=2) + "\n")
    (out_dir / f"bench-{name}.md").write_text(section_markdown(report, name, render))
    return report


def section_markdown(report: dict, name: str, render) -> str:
    """One section's Markdown: a line saying when, where and under what load it was measured
    (its times are absolute on that machine; the ratios are what holds elsewhere), then the section."""
    machine = report["machine"]
    start, end = report["load_average"]
    header = (
        f"Generated by `hydroarm bench --only {name}` on {report['date']}: {machine['cpu_count']} CPUs "
        f"({machine['cpu_model']}), load average {start[0]:.1f} at the start and {end[0]:.1f} at the end"
        + (" (a loaded machine: the absolute times are slower than on a quiet one; the ratios, measured in the same "
           "run, are what counts)" if max(start[0], end[0]) > machine["cpu_count"] else "")
        + "."
    )  # fmt: skip
    return header + "\n" + render(report[name])
