"""The control step of two checkouts side by side: each checkout's ``bench_control_steps`` (section
1 of bench.json: every controller's 10 s paper run, per-phase step times) in its own process,
alternating between the checkouts round by round so that a load change on a shared machine hits
both alike. Writes the medians, p99 and maxima of each controller's whole step per checkout and
round, and the ratio new / old of the medians over the rounds.

    python scripts/bench_side_by_side.py --old /path/to/old/checkout --new . --rounds 2 \\
        --out bench/results/control_step_side_by_side.json
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
from datetime import date
from pathlib import Path

import numpy as np

CHILD = """
import json, sys
from hydroarm_bench.control_steps import bench_control_steps
breakdown, _, _ = bench_control_steps(quick=False)
json.dump({name: phases["total"] for name, phases in breakdown.items()}, sys.stdout)
"""


def measure(checkout: Path) -> dict:
    """One round: every controller's whole-step statistics (ms) in a fresh process of ``checkout``."""
    env = {**os.environ, "PYTHONPATH": f"{checkout / 'src'}{os.pathsep}{checkout / 'bench'}"}
    env.update(OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1", MKL_NUM_THREADS="1")
    out = subprocess.run([sys.executable, "-c", CHILD], env=env, cwd=checkout, capture_output=True, text=True)
    if out.returncode != 0:
        sys.exit(f"{checkout}: the bench failed:\n{out.stderr[-2000:]}")
    return json.loads(out.stdout)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--old", type=Path, required=True, help="the checkout measured as 'old'")
    parser.add_argument("--new", type=Path, required=True, help="the checkout measured as 'new'")
    parser.add_argument("--rounds", type=int, default=2)
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args()
    rounds: dict[str, list[dict]] = {"old": [], "new": []}
    load = [os.getloadavg()]
    for k in range(args.rounds):
        for label in ("old", "new") if k % 2 == 0 else ("new", "old"):
            rounds[label].append(measure(getattr(args, label).resolve()))
            print(f"round {k + 1}: {label} done", flush=True)
        load.append(os.getloadavg())
    ratios = {}
    for name in rounds["new"][0]:
        old = np.median([r[name]["median"] for r in rounds["old"]])
        new = np.median([r[name]["median"] for r in rounds["new"]])
        ratios[name] = {"old_median_ms": old, "new_median_ms": new, "new_over_old": new / old}
        print(f"{name}: median {old:.4f} -> {new:.4f} ms ({new / old:.2f}x)")
    commits = {
        label: subprocess.run(["git", "rev-parse", "HEAD"], cwd=getattr(args, label), capture_output=True,
                              text=True).stdout.strip()
        for label in ("old", "new")
    }  # fmt: skip
    payload = {
        "what": "the whole control step (observe + compute), 10 s paper run per controller, per checkout and round",
        "date": date.today().isoformat(),
        "machine": {"cpus": os.cpu_count(), "processor": platform.processor() or platform.machine()},
        "load_average_between_rounds": load,
        "commits": commits,
        "rounds": rounds,
        "median_over_rounds": ratios,
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(payload, indent=1) + "\n")


if __name__ == "__main__":
    main()
