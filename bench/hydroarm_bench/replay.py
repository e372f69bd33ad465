"""Replaying and calibrating real logs: the three tank trials shipped in tests/data/hinsdale-2023
(the full dataset is not in the repository; docs/validation-real.md gives the campaign's 57-trial
timings). Measured: the wall time of replaying the three trials in this process, per simulated
second, and of calibrating two parameters on two of them (serial, so the numbers do not depend
on the machine's other load through a process pool)."""

from __future__ import annotations

import time
import warnings
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
DATA = ROOT / "tests" / "data" / "hinsdale-2023"
VEHICLE = ROOT / "examples" / "hinsdale" / "bluerov2_hinsdale.toml"


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
    )
