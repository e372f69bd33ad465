"""The measured figures the README, the tutorial, the example sweep and docs/deviations.md state,
from results folders, into docs/data/measured.json (tests/test_doc_figures.py checks the docs
against it).

Usage (after running the commands it reads, on the machine whose figures you want):
    hydroarm reproduce --out results && hydroarm reproduce --quick --out results-quick
    (cd examples/.. && time hydroarm sweep examples/sweep.toml --out sweep1)   # note the seconds
    python scripts/docs_figures.py --full results --quick results-quick --sweep-seconds 101 \\
        --date 2026-12-01 --load "11.2, 7.3, 4.4" --out docs/data/measured.json

The wall times are summary.json's (``wall_time_s.total``: the whole command after its imports);
the ablation figures are its ``ablation`` section (gains: the paper-style mean of per-joint gains
of GP-MPC over MPC, %, clean; costs: the median GP-MPC control step, ms).
"""

from __future__ import annotations

import argparse
import json
import platform
from pathlib import Path


def measured(full: Path, quick: Path, sweep_seconds: float, date: str, load: str) -> dict:
    summary = json.loads((full / "summary.json").read_text())
    quick_summary = json.loads((quick / "summary.json").read_text())
    ablation = summary["ablation"]
    where = ablation["where the estimate enters"]
    steps = ablation["hyperparameter steps per control step"]
    cost = {k: v["GP-MPC"]["step_ms_median"] for k, v in steps.items()}
    return {
        "date": date,
        "machine": {**summary["machine"], "processor": platform.processor() or platform.machine()},
        "load_average": load,
        "reproduce_seconds": round(summary["wall_time_s"]["total"]),
        "reproduce_quick_seconds": round(quick_summary["wall_time_s"]["total"]),
        "sweep_example_seconds": round(sweep_seconds),
        "gain_torque_percent": round(where["torque"]["gain_mean_of_joints"], 1),
        "gain_acceleration_percent": round(where["acceleration"]["gain_mean_of_joints"], 1),
        "hyperparameter_steps_gain_percent": {k: round(v["gain_mean_of_joints"], 1) for k, v in steps.items()},
        "hyperparameter_steps_cost_ratio": {k: round(cost[k] / cost["1"], 1) for k in ("5", "20")},
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--full", type=Path, required=True)
    parser.add_argument("--quick", type=Path, required=True)
    parser.add_argument("--sweep-seconds", type=float, required=True)
    parser.add_argument("--date", required=True)
    parser.add_argument("--load", required=True, help="load average while measuring (uptime)")
    parser.add_argument("--out", type=Path, default=Path("docs/data/measured.json"))
    args = parser.parse_args()
    data = measured(args.full, args.quick, args.sweep_seconds, args.date, args.load)
    args.out.write_text(json.dumps(data, indent=1) + "\n")
    print(json.dumps(data, indent=1))


if __name__ == "__main__":
    main()
