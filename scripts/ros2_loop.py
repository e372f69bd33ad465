"""The ROS 2 loop measured (issue 31; docs/ros2.md): `hydroarm ros2 sim` and `hydroarm ros2
control` as two processes on loopback, on the paper task (10 s):

* lockstep: E_p against the in-process `hydroarm run` of the same controller, settings and seed;
* wall clock at 100 Hz: the period's jitter and the command latency (median, p99, max), the
  commands accepted and stale, and whether the loop diverged.

Writes docs/data/ros2_loop.json (tests/test_doc_figures.py ties docs/ros2.md's numbers to it).

    python scripts/ros2_loop.py [--controller flagship] [--duration 10] [--out docs/data/ros2_loop.json]
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import subprocess
import sys
import tempfile
from pathlib import Path

HYDROARM = [sys.executable, "-m", "hydroarm.cli"]


def pair(controller: str, duration: float, clock: str, domain_id: int, folder: Path) -> dict:
    """Run the two nodes; the sim's ros2_sim.json."""
    common = ["--set", "arm=paper", "--set", f"duration={duration}", "--clock", clock, "--domain-id", str(domain_id)]
    if clock == "lockstep":
        common += ["--command-timeout", "30"]
    sim = subprocess.Popen([*HYDROARM, "ros2", "sim", *common, "--out", str(folder / "sim")], stderr=subprocess.PIPE)
    control = [*HYDROARM, "ros2", "control", "--controller", controller, *common, "--duration", str(duration + 5)]
    subprocess.run([*control, "--out", str(folder / "control")], check=True, capture_output=True, timeout=900)
    sim.communicate(timeout=120)
    return json.loads((folder / "sim" / "ros2_sim.json").read_text())


def in_process(controller: str, duration: float) -> list[float]:
    from hydroarm.sim.experiment import ExperimentConfig, run_experiment, with_overrides
    from hydroarm.sim.runner import tracking_metrics

    config = with_overrides(ExperimentConfig(), {"arm": "paper", "duration": duration})
    return tracking_metrics(run_experiment(config, controller, seed=0))["Ep"]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--controller", default="flagship")
    parser.add_argument("--duration", type=float, default=10.0)
    parser.add_argument("--out", type=Path, default=Path("docs/data/ros2_loop.json"))
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as scratch:
        lockstep = pair(args.controller, args.duration, "lockstep", 71, Path(scratch) / "lockstep")
        wall = pair(args.controller, args.duration, "wall", 72, Path(scratch) / "wall")
    reference = in_process(args.controller, args.duration)
    result = {
        "controller": args.controller,
        "duration_s": args.duration,
        "lockstep": {
            "Ep": lockstep["Ep"],
            "counts": lockstep["counts"],
            "in_process_Ep": reference,
            "equal": lockstep["Ep"] == reference,
        },  # fmt: skip
        "wall": {"Ep": wall["Ep"], "counts": wall["counts"], "diverged": wall["diverged"], **wall["timing"]},
        "machine": {
            "date": datetime.date.today().isoformat(),
            "cpu_count": os.cpu_count(),
            "processor": platform.processor() or platform.machine(),
            "load_average_1min": os.getloadavg()[0],
        },
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=1) + "\n")
    print(json.dumps(result, indent=1))


if __name__ == "__main__":
    main()
