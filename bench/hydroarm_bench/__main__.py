"""``python -m hydroarm_bench --out DIR [--quick] [--only SECTION]`` (with ``bench/`` on ``PYTHONPATH``).

``--only SECTION`` runs one section of :data:`hydroarm_bench.suite.SECTIONS` alone and writes
``DIR/bench-<section>.json`` and ``.md`` (never bench.json: that is the whole suite's).

BLAS is limited to one thread before NumPy is imported (environment variables) and again
with threadpoolctl inside the suite. Prints the targets met and any problem of the
document; exit code 1 when the document is malformed.
"""

from __future__ import annotations

import os

for _name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "BLIS_NUM_THREADS"):
    os.environ.setdefault(_name, "1")

import argparse  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
from pathlib import Path  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    from hydroarm_bench import run_benchmarks, validate_report
    from hydroarm_bench.suite import SECTIONS, run_section

    parser = argparse.ArgumentParser(prog="hydroarm_bench", description="Run the hydroarm benchmark suite.")
    parser.add_argument("--out", type=Path, required=True, help="directory for bench.json and bench.md")
    parser.add_argument("--quick", action="store_true", help="fewer samples and peer problems (CI)")
    parser.add_argument(
        "--only", choices=sorted(SECTIONS), help="run one section alone: writes DIR/bench-<section>.json and .md only"
    )
    args = parser.parse_args(argv)
    if args.only:
        section = run_section(args.out, args.only, quick=args.quick)
        print(json.dumps({"out": str(args.out / f"bench-{args.only}.json"), args.only: section[args.only]}, indent=2))
        return 0
    report = run_benchmarks(args.out, quick=args.quick)
    problems = validate_report(report)
    status = {key: row["met"] for key, row in report["target_status"].items()}
    print(json.dumps({"out": str(args.out), "targets_met": status, "problems": problems}, indent=2))
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
