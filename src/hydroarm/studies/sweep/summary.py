"""A sweep's summary: ``summary.json``, ``summary.md`` and the plots, from the folder alone.

:func:`summarise` joins ``sweep.json``'s rows with their run files and compares the
controllers on the sweep's ``metric`` (:data:`~hydroarm.studies.sweep.schema.METRICS`):
per controller, per value of each swept parameter, and against the tracking bound
(:func:`robustness_table`). It can be called again on a finished folder with another
metric; it runs nothing.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from hydroarm.config import ConfigError, validate
from hydroarm.sim.files import atomic_write
from hydroarm.studies.sweep.plan import value_label
from hydroarm.studies.sweep.plots import (
    plot_metric,
    plot_robustness,
    plot_robustness_by_parameter,
    safe_name,
)
from hydroarm.studies.sweep.results import assess, read_run
from hydroarm.studies.sweep.schema import METRICS, Robustness, unique
from hydroarm.studies.sweep.worker import finite


def _stats(values: list[float]) -> dict:
    finite = np.array([v for v in values if v is not None and math.isfinite(v)], dtype=float)
    if finite.size == 0:
        return {"mean": None, "median": None, "p90": None, "min": None, "max": None}
    return {
        "mean": float(finite.mean()),
        "median": float(np.median(finite)),
        "p90": float(np.percentile(finite, 90)),
        "min": float(finite.min()),
        "max": float(finite.max()),
    }


MAX_GROUPS = 12
"""A parameter with more distinct values than this (or drawn from a range in random mode)
is plotted as a scatter, not boxes."""


def _continuous(plan: dict, rows: list[dict]) -> set[str]:
    """Parameters shown as a scatter, not boxes: drawn from a range, or more than
    ``MAX_GROUPS`` distinct values."""
    sweep = plan["sweep"]
    out = set()
    for key in plan["parameters"]:
        drawn = sweep["mode"] == "random" and isinstance(sweep["parameters"].get(key), dict)
        if drawn or len(unique([value_label(r["params"][key]) for r in rows])) > MAX_GROUPS:
            out.add(key)
    return out


def _load_rows(out: Path) -> tuple[dict, list[dict]]:
    """sweep.json and its rows joined with their run files (``record`` None if not finished)."""
    path = out / "sweep.json"
    if not path.is_file():
        raise ConfigError(f"{out}: no sweep.json (not a sweep folder)")
    plan = json.loads(path.read_text())
    records: dict[str, dict | None] = {}
    rows = []
    for row in plan["rows"]:
        identifier = row["id"]
        if identifier not in records:
            records[identifier] = read_run(out / "runs" / f"{identifier}.json", identifier)
        rows.append({**row, "record": records[identifier]})
    return plan, rows


def robustness_table(rows: list[dict], controllers: list[str], robustness: Robustness) -> dict:
    """Per controller, the runs against the tracking bound (:class:`Robustness`) and the faults.

    ``rows``: plan rows with their run file (``record``, None if not finished).
    Per controller: ``rows`` = ``within`` + ``outside`` (ran to the end, error
    not within the bound) + ``stopped`` (ended early; ``stopped_by`` counts the
    reasons: diverged, controller_error, ...) + ``unfinished`` (failed or not
    run yet); ``short``: runs (among ``outside``) that ended before ``after``;
    ``steady_max_error`` (rad, the largest |q_r - q| from ``after`` on) and
    ``Ep_steady`` (rad^2, mean over joints of E_p after 2 s): mean, median, p90,
    min, max over the runs that ran to the end; ``runs_with_faults`` and
    ``faults``: key -> {"runs": runs with that fault, "events": total count}.
    """
    table: dict[str, dict] = {}
    for name in controllers:
        mine = [r for r in rows if r["controller"] == name]
        done = [r["record"] for r in mine if r["record"] is not None]
        verdicts = [assess(record, robustness) for record in done]
        ran = [(record, v) for record, v in zip(done, verdicts) if v["stopped"] is None]
        within = sum(v["within_bound"] for v in verdicts)
        stopped_by: dict[str, int] = {}
        for v in verdicts:
            if v["stopped"] is not None:
                stopped_by[v["stopped"]] = stopped_by.get(v["stopped"], 0) + 1
        faults: dict[str, dict[str, int]] = {}
        for record in done:
            for key, count in (record.get("faults") or {}).items():
                if count > 0:
                    entry = faults.setdefault(key, {"runs": 0, "events": 0})
                    entry["runs"] += 1
                    entry["events"] += int(count)
        table[name] = {
            "rows": len(mine),
            "finished": len(done),
            "within": within,
            "outside": len(ran) - within,
            "stopped": sum(stopped_by.values()),
            "stopped_by": dict(sorted(stopped_by.items())),
            "unfinished": len(mine) - len(done),
            "short": sum(math.isnan(v["steady_max_error"]) for _, v in ran),
            "steady_max_error": _stats([v["steady_max_error"] for _, v in ran]),
            "Ep_steady": _stats([record["summary"].get("Ep_steady_mean") for record, _ in ran]),
            "runs_with_faults": sum(bool(any(c > 0 for c in (r.get("faults") or {}).values())) for r in done),
            "faults": dict(sorted(faults.items())),
        }
    return {"bound": robustness.model_dump(), "controllers": table}


def summarise(out_dir: str | Path, metric: str | None = None) -> dict:
    """Write ``summary.md``, ``summary.json`` and the plots of a sweep folder; return the summary.

    ``metric``: a key of :data:`METRICS` (default: the sweep file's ``metric``,
    the mean E_p over joints). Per controller: rows, finished, diverged runs and
    mean/median/p90/min/max of the metric; per swept parameter with at most
    ``MAX_GROUPS`` values that are not drawn from a range: the same per value
    and controller (the others are plotted as a scatter); ``robustness``: the
    runs against the sweep's tracking bound and the fault counts per controller
    (:func:`robustness_table`).
    """
    out = Path(out_dir)
    plan, rows = _load_rows(out)
    metric = metric or plan["sweep"].get("metric", "Ep_mean")
    if metric not in METRICS:
        raise ConfigError(f"metric '{metric}': must be one of {', '.join(METRICS)}")
    controllers = plan["sweep"]["controllers"]
    robustness = validate(Robustness, plan["sweep"].get("robustness", {}), f"{out}/sweep.json: robustness")
    finished = [r for r in rows if r["record"] is not None]

    def group(selected: list[dict]) -> dict:
        return {
            "finished": len(selected),
            "diverged": sum(bool(r["record"]["summary"]["diverged"]) for r in selected),
            **_stats([r["record"]["summary"].get(metric) for r in selected]),
        }

    per_controller = {}
    for name in controllers:
        mine = [r for r in rows if r["controller"] == name]
        per_controller[name] = {"rows": len(mine), **group([r for r in mine if r["record"] is not None])}
    by_parameter: dict[str, dict] = {}
    varying = []
    continuous = _continuous(plan, rows)
    for key in plan["parameters"]:
        labels = unique([value_label(r["params"][key]) for r in rows])
        if len(labels) < 2:
            continue
        varying.append(key)
        if key in continuous:
            by_parameter[key] = {"values": len(labels), "grouped": False}
            continue
        groups = {
            label: {
                name: group([r for r in finished if r["controller"] == name and value_label(r["params"][key]) == label])
                for name in controllers
            }
            for label in labels
        }
        by_parameter[key] = {"values": len(labels), "grouped": True, "groups": groups}
    summary = {
        "name": plan["sweep"]["name"],
        "out": str(out),
        "metric": metric,
        "metric_label": f"{METRICS[metric][0]} ({METRICS[metric][1].replace('$^2$', '^2')})",
        "rows": len(rows),
        "runs": len({r["id"] for r in rows}),
        "finished_rows": len(finished),
        "controllers": per_controller,
        "parameters": plan["parameters"],
        "varying": varying,
        "by_parameter": by_parameter,
        "robustness": robustness_table(rows, controllers, robustness),
    }
    failed_path = out / "failed.json"
    summary["failed_runs"] = json.loads(failed_path.read_text()) if failed_path.is_file() else []
    summary["plots"] = plot_metric(out, controllers, finished, varying, continuous, metric)
    plot = plot_robustness(out, controllers, finished, robustness)
    if plot:
        summary["plots"]["robustness"] = plot
    plot = plot_robustness_by_parameter(out, controllers, finished, varying, robustness)
    if plot:
        summary["plots"]["robustness_by_parameter"] = plot
    atomic_write(out / "summary.json", json.dumps(finite(summary), indent=1))
    atomic_write(out / "summary.md", _markdown(summary, plan))
    return summary


def _fmt(value: float | None) -> str:
    return "-" if value is None else f"{value:.4g}"


def _markdown(summary: dict, plan: dict) -> str:
    sweep = plan["sweep"]
    seeds = sweep["seeds"] if isinstance(sweep["seeds"], list) else list(range(sweep["seeds"]))
    label = summary["metric_label"]
    lines = [f"# Sweep `{summary['name']}`", ""]
    if sweep.get("description"):
        lines += [sweep["description"], ""]
    lines += [
        f"{summary['finished_rows']} of {summary['rows']} rows finished ({summary['runs']} distinct runs: rows that "
        "differ only in another controller's settings share one run). Mode "
        f"`{sweep['mode']}`; controllers {', '.join(sweep['controllers'])}; seeds {seeds}; "
        f"arm `{sweep['base']['arm']}` unless swept; {sweep['base']['duration']:g} s per run. "
        "Every setting and metric of every run: `results.csv`; one file per run: `runs/<id>.json`.",
        "",
        f"## {label[0].upper() + label[1:]}, per controller",
        "",
        "| controller | rows | finished | mean | median | p90 | min | max | diverged |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for name, s in summary["controllers"].items():
        lines.append(
            f"| {name} | {s['rows']} | {s['finished']} | {_fmt(s['mean'])} | {_fmt(s['median'])} | "
            f"{_fmt(s['p90'])} | {_fmt(s['min'])} | {_fmt(s['max'])} | {s['diverged']} |"
        )
    lines += ["", "A diverged run's metrics are over the steps before it stopped.", ""]
    for name in ("ep_boxplot", "ep_distribution"):
        if name in summary["plots"]:
            lines += [f"![{name}]({summary['plots'][name]})", ""]
    lines += _robustness_markdown(
        summary["robustness"], summary["plots"].get("robustness"), summary["plots"].get("robustness_by_parameter")
    )
    for key, entry in summary["by_parameter"].items():
        lines += [f"## By `{key}`", ""]
        if not entry["grouped"]:
            lines += [f"{entry['values']} distinct values: see the scatter plot.", ""]
        else:
            names = list(summary["controllers"])
            lines += ["| " + key + " | " + " | ".join(f"{n}: median (runs)" for n in names) + " |",
                      "|---" * (len(names) + 1) + "|"]  # fmt: skip
            for value, group in entry["groups"].items():
                cells = [f"{_fmt(group[n]['median'])} ({group[n]['finished']})" for n in names]
                lines.append(f"| {value} | " + " | ".join(cells) + " |")
            lines.append("")
        plot = summary["plots"].get(f"ep_by_{safe_name(key)}")
        if plot:
            lines += [f"![{label} by {key}]({plot})", ""]
    if summary["failed_runs"]:
        lines += ["## Failed runs (retried by the next call)", ""]
        lines += [f"- `{f['id']}` {f['controller']} seed {f['seed']}: {f['error']}" for f in summary["failed_runs"]]
        lines.append("")
    return "\n".join(lines)


def _robustness_markdown(robustness: dict, plot: str | None, by_parameter: str | None = None) -> list[str]:
    """The robustness section of summary.md: runs within the bound, faults, the plot."""
    bound, table = robustness["bound"], robustness["controllers"]
    after, limit = bound["after"], bound["max_error"]
    lines = [
        "## Robustness: runs within the tracking bound",
        "",
        f"Within the bound: the run ran to the end (not diverged, not stopped) and from t = {after:g} s on "
        f"|q_r - q| < {limit:g} rad on every joint at every control step (true q). rows = within + outside + "
        "stopped + not finished. The error columns are over the runs that ran to the end: the largest "
        f"|q_r - q| from {after:g} s on (rad) and the mean over joints of E_p after 2 s (rad^2).",
        "",
        "| controller | rows | within bound | outside | stopped | not finished | max error: median | p90 "
        "| E_p after 2 s: median | p90 | runs with faults |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for name, s in table.items():
        why = ", ".join(f"{k} {v}" for k, v in s["stopped_by"].items())
        stopped = f"{s['stopped']} ({why})" if why else "0"
        lines.append(
            f"| {name} | {s['rows']} | {s['within']} | {s['outside']} | {stopped} | {s['unfinished']} | "
            f"{_fmt(s['steady_max_error']['median'])} | {_fmt(s['steady_max_error']['p90'])} | "
            f"{_fmt(s['Ep_steady']['median'])} | {_fmt(s['Ep_steady']['p90'])} | {s['runs_with_faults']} |"
        )
    lines.append("")
    short = sum(s["short"] for s in table.values())
    if short:
        lines += [f"{short} runs ended before {after:g} s: they cannot be within the bound (`[robustness] after`).", ""]
    keys = sorted({key for s in table.values() for key in s["faults"]})
    if keys:
        lines += [
            "Faults the runner counted (runs with the fault / events over those runs):",
            "",
            "| fault | " + " | ".join(table) + " |",
            "|---" * (len(table) + 1) + "|",
        ]
        for key in keys:
            cells = [
                f"{s['faults'][key]['runs']} / {s['faults'][key]['events']}" if key in s["faults"] else "0"
                for s in table.values()
            ]
            lines.append(f"| {key} | " + " | ".join(cells) + " |")
        lines.append("")
    else:
        lines += ["No fault was counted in any finished run.", ""]
    if plot:
        lines += [f"![fraction of runs within a bound]({plot})", ""]
    if by_parameter:
        lines += [f"![the largest error after {after:g} s by parameter]({by_parameter})", ""]
    return lines
