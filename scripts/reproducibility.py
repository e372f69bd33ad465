"""Which digits of a reproduction reproduce: compare the numbers of two (or more) summary.json
files of `hydroarm reproduce` made under different compilations or BLAS kernels, row by row.

    python scripts/reproducibility.py --reference A/summary.json --label "default" \
        --variant B/summary.json "numba generic x86-64" --variant C/summary.json "OpenBLAS Haswell" \
        --out docs/data/reproducibility

Writes ``OUT.json`` (per variant and table row: numbers compared, numbers that differ, the
largest relative difference) and ``OUT.md`` (the same as a table). Timings and machine facts are
left out.
"""

from __future__ import annotations

import argparse
import json
import math
import re
from collections import defaultdict
from pathlib import Path

TIMING = re.compile(r"(_ms|seconds|_s$|time|wall|elapsed)")
SKIP = ("/machine", "/settings", "/files", "/wall_time_s")


def compare(reference: dict, other: dict) -> dict[str, dict]:
    """Per row (``table/row``, e.g. ``clean/GP-MPC``): numbers compared, differing, max relative difference."""
    rows: dict[str, dict] = defaultdict(lambda: {"numbers": 0, "differ": 0, "max_relative": 0.0})

    def walk(a, b, path: str) -> None:
        if isinstance(a, dict) and isinstance(b, dict):
            for key in a:
                if key in b:
                    walk(a[key], b[key], f"{path}/{key}")
        elif isinstance(a, list) and isinstance(b, list) and len(a) == len(b):
            for i, (x, y) in enumerate(zip(a, b)):
                walk(x, y, f"{path}[{i}]")
        elif isinstance(a, (int, float)) and isinstance(b, (int, float)) and not isinstance(a, bool):
            last = path.split("/")[-1].split("[")[0]
            if TIMING.search(last) or path.startswith(SKIP):
                return
            row = rows["/".join(path.split("/")[1:3])]
            row["numbers"] += 1
            if a != b and not (math.isnan(a) and math.isnan(b)):
                row["differ"] += 1
                row["max_relative"] = max(row["max_relative"], abs(a - b) / max(abs(a), abs(b), 1e-300))

    walk(reference, other, "")
    return dict(sorted(rows.items()))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--reference", type=Path, required=True)
    parser.add_argument("--label", default="reference")
    parser.add_argument("--variant", nargs=2, action="append", metavar=("SUMMARY", "LABEL"), required=True)
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args()
    reference = json.loads(args.reference.read_text())
    result = {"reference": args.label, "variants": {}}
    for path, label in args.variant:
        result["variants"][label] = compare(reference, json.loads(Path(path).read_text()))
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.with_suffix(".json").write_text(json.dumps(result, indent=1) + "\n")
    lines = [f"Against `{args.label}`: numbers that differ / numbers compared, largest relative difference.", ""]
    labels = list(result["variants"])
    lines += ["| row | " + " | ".join(labels) + " |", "|---|" + "---|" * len(labels)]
    keys = sorted({key for rows in result["variants"].values() for key in rows})
    for key in keys:
        cells = []
        for label in labels:
            row = result["variants"][label].get(key)
            cells.append("-" if row is None else f"{row['differ']}/{row['numbers']}, {row['max_relative']:.1e}")
        lines.append(f"| {key} | " + " | ".join(cells) + " |")
    args.out.with_suffix(".md").write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
