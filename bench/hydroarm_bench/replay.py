"""Replaying and calibrating real logs.

Always: the three tank trials shipped in tests/data/hinsdale-2023: the wall time of replaying
them in this process, per simulated second, and of calibrating two parameters on two of them
(serial, so the numbers do not depend on the machine's other load through a process pool).

With the whole dataset (not in the repository: the environment variable
``HYDROARM_HINSDALE_TRIALS`` names its ``trials`` folder), the issue's two targets, as a user
runs them on 2 cores (2 worker processes, pool start-up included): replaying all 57 arm-motion
trials, and calibrating 4 parameters on 6 trials (split A of docs/validation-real.md), each
<= 60 s. ``python -m hydroarm_bench.replay --merge bench/results/bench.json`` measures this
section alone and writes it into an existing bench.json (and bench.md beside it)."""

from __future__ import annotations

import argparse
import json
import os
import time
import warnings
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
DATA = ROOT / "tests" / "data" / "hinsdale-2023"
VEHICLE = ROOT / "examples" / "hinsdale" / "bluerov2_hinsdale.toml"
FULL_ENV = "HYDROARM_HINSDALE_TRIALS"
TRAIN = ["traj_alt_001-0", "traj_alt_001-1", "traj_alt_002-0", "traj_alt_008-0", "traj_alt_009-1", "traj_alt_011-0"]
FOUR = ["cb_x", "cb_y", "cb_z", "rotational_damping_scale"]


def bench_full(workers: int = 2) -> dict:
    """The whole dataset's timings (module docstring), or ``{"skipped": why}``."""
    from hydroarm.studies.calibrate import calibrate
    from hydroarm.studies.replay import ReplayConfig, load_vehicle_quietly, replay_many

    folder = os.environ.get(FULL_ENV)
    if not folder:
        return {"skipped": f"set {FULL_ENV} to the Hinsdale 2023 dataset's trials folder"}
    paths = sorted(p for p in Path(folder).glob("traj*_joint_states.csv") if "-test" not in p.name)
    by_name = {p.name.removesuffix("_joint_states.csv"): p for p in paths}
    if len(paths) != 57 or set(TRAIN) - set(by_name):
        return {"skipped": f"{folder}: {len(paths)} arm-motion trials, not the dataset's 57"}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        spec = load_vehicle_quietly(VEHICLE)
        config = ReplayConfig()
        replay_many(paths[:1], spec, "mount", config, workers=0)  # compile (the numba cache) first
        began = time.perf_counter()
        results = replay_many(paths, spec, "mount", config, workers=workers)
        replay_s = time.perf_counter() - began
        fit = calibrate([by_name[n] for n in TRAIN], spec, "mount", FOUR, config, workers=workers)
    return {
        "workers": workers,
        "trials": len(results),
        "simulated_s": sum(float(r.time[-1] - r.time[0]) for r in results),
        "replay_all_s": replay_s,
        "calibrate_trials": TRAIN,
        "calibrate_parameters": FOUR,
        "calibrate_s": fit.seconds,
        "calibrate_replays": fit.evaluations,
        "load_average": list(os.getloadavg()),
    }


def bench_replay(quick: bool) -> dict:
    """``{"replay_s", "simulated_s", "replay_per_simulated_s", "calibrate_s", "calibrate_replays"}``."""
    from hydroarm.studies.calibrate import calibrate
    from hydroarm.studies.replay import ReplayConfig, load_vehicle_quietly, replay_many

    paths = sorted(DATA.glob("*_joint_states.csv"))
    if not paths:
        return {"skipped": f"no trials in {DATA}"}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        spec = load_vehicle_quietly(VEHICLE)
        config = ReplayConfig()
        replay_many(paths[:1], spec, "mount", config, workers=0)  # compile and warm
        began = time.perf_counter()
        results = replay_many(paths, spec, "mount", config, workers=0)
        replay_s = time.perf_counter() - began
        simulated = sum(float(r.time[-1] - r.time[0]) for r in results)
        names = ["rotational_damping_scale"] if quick else ["cb_x", "rotational_damping_scale"]
        fit = calibrate(paths[:2], spec, "mount", names, config, workers=0)
    return {
        "trials": len(paths),
        "replay_s": replay_s,
        "simulated_s": simulated,
        "replay_per_simulated_s": replay_s / simulated,
        "calibrate_parameters": names,
        "calibrate_s": fit.seconds,
        "calibrate_replays": fit.evaluations,
        "full": bench_full(),
    }


def render_replay(section: dict) -> str:
    """The replay's section of bench.md."""
    if "skipped" in section:
        return f"\n## Replaying real logs\n\nSkipped: {section['skipped']}\n"
    return (
        "\n## Replaying real logs\n\n"
        f"{section['trials']} shipped tank trials ({section['simulated_s']:.0f} s of logs) replayed in "
        f"{section['replay_s']:.2f} s in one process ({1e3 * section['replay_per_simulated_s']:.1f} ms per "
        f"logged second); calibrating {', '.join(section['calibrate_parameters'])} on two of them: "
        f"{section['calibrate_s']:.1f} s ({section['calibrate_replays']} replays of the two).\n"
        + _render_full(section.get("full"))
    )


def _render_full(full: dict | None) -> str:
    if not full:
        return ""
    if "skipped" in full:
        return f"\nThe whole dataset: skipped ({full['skipped']}).\n"
    return (
        f"\nThe whole dataset ({full['workers']} worker processes, load average "
        f"{full['load_average'][0]:.1f} at the end): all {full['trials']} trials ({full['simulated_s']:.0f} s of "
        f"logs) replayed in {full['replay_all_s']:.1f} s (target <= 60 s); "
        f"{len(full['calibrate_parameters'])} parameters ({', '.join(full['calibrate_parameters'])}) calibrated on "
        f"{len(full['calibrate_trials'])} trials in {full['calibrate_s']:.1f} s ({full['calibrate_replays']} "
        "replays of the six; target <= 60 s).\n"
    )


def merge(path: Path) -> dict:
    """Measure this section alone and write it into the bench.json at ``path`` (and its bench.md)."""
    from hydroarm_bench.envs import render_envs
    from hydroarm_bench.markdown import render_markdown
    from hydroarm_bench.report import target_status
    from hydroarm_bench.stats import TARGETS
    from hydroarm_bench.uvms import render_uvms
    from hydroarm_bench.viewer import render_viewer

    report = json.loads(path.read_text())
    report["replay"] = bench_replay(bool(report.get("quick")))
    try:
        report["target_status"] = target_status(report)
    except KeyError:  # a bench.json of an older schema: only this section's targets are added
        full = report["replay"].get("full", {})
        for key, value in (
            ("replay_all_trials_s", full.get("replay_all_s")),
            ("calibrate_4_on_6_s", full.get("calibrate_s")),
        ):
            target = TARGETS[key]
            met = None if value is None else bool(value <= target)
            report.setdefault("target_status", {})[key] = {"measured": value, "target": target, "met": met}
    report.setdefault("targets", {}).update({k: TARGETS[k] for k in ("replay_all_trials_s", "calibrate_4_on_6_s")})
    path.write_text(json.dumps(report, indent=2) + "\n")
    try:
        markdown = render_markdown(report) + render_uvms(report["uvms"]) + render_viewer(report["viewer"])
        markdown += render_envs(report["envs"]) + render_replay(report["replay"])
    except KeyError:  # an older schema: bench.md keeps its sections and gains this one's
        old = path.with_name("bench.md").read_text()
        markdown = old.split("\n## Replaying real logs\n")[0].rstrip("\n") + "\n" + render_replay(report["replay"])
    path.with_name("bench.md").write_text(markdown)
    return report["replay"]


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description="Measure the replay section alone into an existing bench.json.")
    parser.add_argument("--merge", type=Path, required=True, help="the bench.json to update")
    print(json.dumps(merge(parser.parse_args().merge), indent=1))
