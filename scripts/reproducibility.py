"""Which digits of a reproduction reproduce: compare the numbers of two (or more) summary.json
files of `hydroarm reproduce` made under different compilations or BLAS kernels, row by row.

    python scripts/reproducibility.py --reference A/summary.json --label "default" \
        --variant B/summary.json "numba generic x86-64" --variant C/summary.json "OpenBLAS Haswell" \
        --out docs/data/reproducibility [--check]

Every number but the timings and machine facts is compared. A row the reproduction reports as a
distribution (``replicas`` in the clean case, ``Ep_spread`` in the noisy case: the rows whose
closed loop turns a last-bit difference into another run) is judged on the E_p it prints (the
replicas' mean per joint and of the joints, or the mean over seeds): the two means must differ by
at most the runs' ranges (max - min of each file's replicas or seeds, added: for 4 runs a file
about 4.1 standard deviations of one run, where the difference of the means has 0.71; for 8, 5.7
against 0.5). The table gives the difference in standard errors too. Every other row must agree
to 1e-9 relative. The ablation tables are split by controller (``ablation/GROUP/CONTROLLER``):
their MPC and IDMPC runs are judged to 1e-9 like any plain row; their GP cells (GP-MPC,
GP-IDMPC), replicated by the reproduction like the main GP rows, within their runs' ranges, cell by
cell (the worst cell is the row's). A GP cell of an older summary without replicas is marked
``chaotic`` when it differs (reported, not failed on: only a replicated cell can hold).

Writes ``OUT.json`` (per variant and row: numbers compared, numbers that differ, the largest
relative difference, and for a distribution row the largest difference in standard errors and in
spreads) and ``OUT.md`` (the same as a table). ``--check``: exit 1 if a row fails.
"""

from __future__ import annotations

import argparse
import json
import math
import re
import sys
from collections import defaultdict
from pathlib import Path

TIMING = re.compile(r"(_ms|seconds|_s$|time|wall|elapsed)")
SKIP = ("/machine", "/settings", "/files", "/wall_time_s")
RELATIVE = 1e-9
"""Rows without a spread: the largest relative difference allowed."""
DERIVED = ("best", "gain_gp_mpc_over_mpc_percent")
"""Blocks computed from the distribution rows (which row wins, GP-MPC's gain): compared, not judged;
the tables print them from the rows' held numbers."""


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
            row = rows[_row_key(reference, path)]
            row["numbers"] += 1
            if a != b and not (math.isnan(a) and math.isnan(b)):
                row["differ"] += 1
                row["max_relative"] = max(row["max_relative"], abs(a - b) / max(abs(a), abs(b), 1e-300))

    walk(reference, other, "")
    result = dict(sorted(rows.items()))
    for key, row in result.items():
        case, _, name = key.partition("/")
        a, b = reference.get(case, {}).get(name), other.get(case, {}).get(name)
        judged = _distribution(a, b) if isinstance(a, dict) and isinstance(b, dict) else None
        if name in DERIVED or (case in ABLATIONS and key.endswith("/" + GAIN)):
            row["holds"], row["derived"] = True, True
        elif case in ABLATIONS and key.rpartition("/")[2].startswith("GP-"):
            judged = _ablation_distribution(reference, other, key)
            if judged is not None:
                row.update(judged)
                row["holds"] = row["max_relative"] <= RELATIVE or judged["max_ranges"] <= 1.0
            else:
                row["holds"] = row["max_relative"] <= RELATIVE
                row["chaotic"] = not row["holds"]
        elif judged is not None:
            row.update(judged)
            row["holds"] = judged["max_ranges"] <= 1.0
        else:
            row["holds"] = row["max_relative"] <= RELATIVE
    return result


ABLATIONS = ("ablation", "ablation_idmpc")
GAIN = "gain"
"""The ablation tables (split by controller) and the key of their derived gains."""


def _row_key(reference: dict, path: str) -> str:
    """The row a number at ``path`` (``/table/row/...``) belongs to: ``table/row``, or in an
    ablation table ``table/group/controller`` (``table/group/gain`` for a derived gain)."""
    parts = path.split("/")[1:]
    if parts[0] not in ABLATIONS or len(parts) < 4:
        return "/".join(parts[:2])
    table, group, label, field = parts[0], parts[1], parts[2], parts[3].split("[")[0]
    entry = reference[table][group][label]
    if "controller" in entry:  # ablation_idmpc: one controller per setting
        return f"{table}/{group}/{entry['controller']}"
    if isinstance(entry.get(field), dict):  # ablation: the settings' MPC and GP-MPC side by side
        return f"{table}/{group}/{field}"
    return f"{table}/{group}/{GAIN}"


def _runs(entry: dict) -> list[list[float]] | None:
    """The runs a distribution row's printed E_p is the mean of, (K, n + 1): each run's E_p per
    joint and its mean of joints (the replicas in the clean case, the seeds in the noisy one);
    None for a row without a spread."""
    if entry.get("replicas") is not None:
        runs = entry["replicas"]["Ep_per_replica"]
    elif entry.get("Ep_spread") is not None:
        runs = entry["Ep_per_seed"]
    else:
        return None
    return [[*run, sum(run) / len(run)] for run in runs]


def _distribution(a: dict, b: dict) -> dict | None:
    """The largest difference of the two means of a distribution row, in standard errors of the
    difference and in units of the runs' ranges (max - min of each file's runs, added)."""
    runs_a, runs_b = _runs(a), _runs(b)
    if runs_a is None or runs_b is None:
        return None
    worst_se, worst_range = 0.0, 0.0
    for j in range(len(runs_a[0])):
        x, y = [run[j] for run in runs_a], [run[j] for run in runs_b]
        difference = abs(sum(x) / len(x) - sum(y) / len(y))
        if difference == 0.0:
            continue
        se = math.hypot(_std(x) / math.sqrt(len(x)), _std(y) / math.sqrt(len(y)))
        worst_se = max(worst_se, difference / se if se > 0 else math.inf)
        ranges = max(x) - min(x) + max(y) - min(y)
        worst_range = max(worst_range, difference / ranges if ranges > 0 else math.inf)
    return {"distribution": True, "max_standard_errors": worst_se, "max_ranges": worst_range}


def _ablation_distribution(reference: dict, other: dict, key: str) -> dict | None:
    """An ablation table's GP row (``table/group/controller``) judged cell by cell (each setting's
    replicas, :func:`_distribution`), the worst cell's numbers; None if a cell has no replicas."""
    table, group, controller = key.split("/")
    worst = None
    for label, a in reference[table][group].items():
        b = other.get(table, {}).get(group, {}).get(label)
        if "controller" not in a:  # ablation: the settings' MPC and GP-MPC side by side
            a, b = a.get(controller), (b or {}).get(controller)
        elif a["controller"] != controller:
            continue
        if not isinstance(a, dict) or not isinstance(b, dict):
            continue
        judged = _distribution(a, b)
        if judged is None:
            return None
        if worst is None or judged["max_ranges"] > worst["max_ranges"]:
            worst = judged
    return worst


def _std(values: list[float]) -> float:
    if len(values) < 2:
        return 0.0
    mean = sum(values) / len(values)
    return math.sqrt(sum((v - mean) ** 2 for v in values) / (len(values) - 1))


def _cell(row: dict | None) -> str:
    if row is None:
        return "-"
    text = f"{row['differ']}/{row['numbers']}, {row['max_relative']:.1e}"
    if row.get("distribution"):
        text += f"; E_p {row['max_ranges']:.2g} of the runs' ranges ({row['max_standard_errors']:.2g} SE)"
    if row.get("derived"):
        text += " (derived)"
    if row.get("chaotic"):
        return text + " (single run of a GP loop, not replicated: does not hold)"
    return text + ("" if row["holds"] else " **FAILS**")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--reference", type=Path, required=True)
    parser.add_argument("--label", default="reference")
    parser.add_argument("--variant", nargs=2, action="append", metavar=("SUMMARY", "LABEL"), required=True)
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--check", action="store_true", help="exit 1 if a row does not hold")
    args = parser.parse_args()
    reference = json.loads(args.reference.read_text())
    result = {"reference": args.label, "relative": RELATIVE, "variants": {}}
    for path, label in args.variant:
        result["variants"][label] = compare(reference, json.loads(Path(path).read_text()))
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.with_suffix(".json").write_text(json.dumps(result, indent=1) + "\n")
    lines = [
        f"Against `{args.label}`: numbers that differ / numbers compared, largest relative difference; for a row",
        "reported as a distribution (its replicas' or seeds' mean ± spread) also the largest difference of",
        "the E_p it prints (its mean per joint and of the joints), as a fraction of the runs' ranges (max -",
        "min of each file's replicas or seeds, added) and in standard errors of the difference (SE). A row",
        f"holds if it agrees to {RELATIVE:g} relative, or (a distribution row) within the runs' ranges;",
        "**FAILS** marks one that does not. The ablations are split by controller; their GP cells are",
        "replicated like the main GP rows and judged cell by cell (the worst cell shown). Derived numbers",
        "(which row wins, gains) are compared, not judged.",
        "",
    ]
    labels = list(result["variants"])
    lines += ["| row | " + " | ".join(labels) + " |", "|---|" + "---|" * len(labels)]
    keys = sorted({key for rows in result["variants"].values() for key in rows})
    for key in keys:
        lines.append(f"| {key} | " + " | ".join(_cell(result["variants"][label].get(key)) for label in labels) + " |")
    args.out.with_suffix(".md").write_text("\n".join(lines) + "\n")
    failed = []
    for label in labels:
        for key, row in result["variants"][label].items():
            if row.get("chaotic"):
                print(f"{label}: {key} differs (a single run of a GP loop, not replicated)", file=sys.stderr)
            elif not row["holds"]:
                print(f"{label}: {key} does not hold", file=sys.stderr)
                failed.append((label, key))
    if args.check and failed:
        sys.exit(1)


if __name__ == "__main__":
    main()
