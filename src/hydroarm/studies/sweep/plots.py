"""The plots of a sweep's summary (PNG, headless): the metric per controller and per swept
parameter, and the runs against the tracking bound. matplotlib is imported on the first
plot, so a sweep worker never loads it."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from hydroarm.studies.outputs import slug
from hydroarm.studies.sweep.plan import value_label
from hydroarm.studies.sweep.results import assess
from hydroarm.studies.sweep.schema import METRICS, Robustness, unique


def _pyplot():
    """What the plots draw with: :func:`hydroarm.studies.figures.subplots` (no pyplot, no backend)."""
    from hydroarm.studies import figures

    return figures


def _colour(name: str, default: str | None = None) -> str | None:
    """A controller's colour, the same as in the reproduction's figures."""
    from hydroarm.studies.figures import COLOURS

    return COLOURS.get(name, default)


def safe_name(key: str) -> str:
    """A parameter key as part of a file name (``mpc.r`` -> ``mpc_r``): the one
    :func:`~hydroarm.studies.outputs.slug`, dots as underscores."""
    return slug(key).replace(".", "_")


def plot_metric(
    out: Path, controllers: list[str], finished: list[dict], varying: list[str], continuous: set[str], metric: str
) -> dict[str, str]:
    """ep_boxplot.png, ep_distribution.png and ep_by_<key>.png; returns name -> file."""
    label = f"{METRICS[metric][0]} ({METRICS[metric][1]})"

    def values(rows: list[dict]) -> list[float]:
        got = (r["record"]["summary"].get(metric) for r in rows)
        return [v for v in got if v is not None and math.isfinite(v)]

    plots: dict[str, str] = {}
    per = {name: values([r for r in finished if r["controller"] == name]) for name in controllers}
    everything = [v for vs in per.values() for v in vs]
    if not everything:
        return plots
    names = [n for n in controllers if per[n]]
    single = varying[0] if len(varying) == 1 and varying[0] not in continuous else None
    _box_figure(out / "ep_boxplot.png", controllers, finished, names, per, single, values, label)
    plots["ep_boxplot"] = "ep_boxplot.png"
    _distribution_figure(out / "ep_distribution.png", names, per, label)
    plots["ep_distribution"] = "ep_distribution.png"
    for key in varying:
        name = f"ep_by_{safe_name(key)}"
        _by_key_figure(out / f"{name}.png", key, key in continuous, controllers, finished, names, values, metric, label)
        plots[name] = f"{name}.png"
    return plots


def _wide(data: list[float]) -> bool:
    """Whether ``data`` spans more than a factor 20 (all positive): then on a log axis."""
    return bool(data) and min(data) > 0.0 and max(data) / min(data) > 20.0


def _scale(ax, data: list[float]) -> None:
    if _wide(data):
        ax.set_yscale("log")


def _box_figure(
    path: Path, controllers: list[str], finished: list[dict], names: list[str], per: dict[str, list[float]],
    single: str | None, values, label: str,
) -> None:  # fmt: skip
    """Box plots of the metric per controller, and by ``single`` (a discrete parameter) beside them."""
    plt = _pyplot()
    everything = [v for vs in per.values() for v in vs]
    fig, axes = plt.subplots(1, 2 if single else 1, figsize=(11 if single else 6, 4.2), squeeze=False)
    ax = axes[0, 0]
    box = ax.boxplot([per[n] for n in names], tick_labels=names, patch_artist=True, medianprops={"color": "black"})
    for patch, name in zip(box["boxes"], names):
        patch.set_facecolor(_colour(name, "lightgrey"))
        patch.set_alpha(0.5)
    _scale(ax, everything)
    ax.set_ylabel(label)
    ax.set_title("per controller")
    ax.grid(True, axis="y", alpha=0.3)
    if single:
        _grouped_boxes(axes[0, 1], single, controllers, finished, values, label)
        _scale(axes[0, 1], everything)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def _distribution_figure(path: Path, names: list[str], per: dict[str, list[float]], label: str) -> None:
    """The metric's empirical distribution function per controller."""
    plt = _pyplot()
    everything = [v for vs in per.values() for v in vs]
    fig, ax = plt.subplots(figsize=(6, 4.2))
    for name in names:
        data = np.sort(per[name])
        fraction = np.arange(0, data.size + 1) / data.size
        ax.step(np.r_[data[0], data], fraction, where="post", label=name, color=_colour(name))
    if _wide(everything):
        ax.set_xscale("log")
    ax.set_xlabel(label)
    ax.set_ylabel("fraction of runs <= x")
    ax.set_title("distribution per controller")
    ax.grid(True, alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def _by_key_figure(
    path: Path, key: str, continuous: bool, controllers: list[str], finished: list[dict], names: list[str],
    values, metric: str, label: str,
) -> None:  # fmt: skip
    """The metric against parameter ``key``: a scatter if it is continuous, else box plots per value."""
    plt = _pyplot()
    everything = [v for name in names for v in values([r for r in finished if r["controller"] == name])]
    fig, ax = plt.subplots(figsize=(8, 4.2))
    if continuous:
        for name in names:
            mine = [r for r in finished if r["controller"] == name]
            xs = [r["params"][key] for r in mine]
            ys = [r["record"]["summary"].get(metric) for r in mine]
            ys = [math.nan if y is None else y for y in ys]
            ax.scatter(xs, ys, s=14, alpha=0.7, label=name, color=_colour(name))
        numeric = [r["params"][key] for r in finished if isinstance(r["params"][key], (int, float))]
        if numeric and min(numeric) > 0 and max(numeric) / min(numeric) > 50:
            ax.set_xscale("log")
        ax.set_xlabel(key)
        ax.set_ylabel(label)
        ax.legend()
        ax.grid(True, alpha=0.3)
    else:
        _grouped_boxes(ax, key, controllers, finished, values, label)
    _scale(ax, everything)
    ax.set_title(f"by {key}")
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def plot_robustness(out: Path, controllers: list[str], finished: list[dict], robustness: Robustness) -> str | None:
    """robustness.png: per controller, the fraction of finished runs that ran to the end with
    the largest |q_r - q| from ``after`` on below x (a run that stopped never counts), and the
    sweep's bound; returns the file name (None if no run finished)."""
    plt = _pyplot()

    curves = {}
    for name in controllers:
        verdicts = [assess(r["record"], robustness) for r in finished if r["controller"] == name]
        errors = [v["steady_max_error"] for v in verdicts if v["stopped"] is None]
        curves[name] = (np.sort([e for e in errors if math.isfinite(e)]), len(verdicts))
    values = np.concatenate([c[0] for c in curves.values()]) if curves else np.zeros(0)
    if values.size == 0:
        return None
    fig, ax = plt.subplots(figsize=(6.4, 4.2))
    low, high = min(values.min(), robustness.max_error), max(values.max(), robustness.max_error)
    for name, (errors, count) in curves.items():
        if count == 0:
            continue
        xs = np.r_[low, errors, high]
        fraction = np.r_[0.0, np.arange(1, errors.size + 1), errors.size] / count
        ax.step(xs, fraction, where="post", label=f"{name} ({count} runs)", color=_colour(name))
    bound = f"bound {robustness.max_error:g} rad"
    ax.axvline(robustness.max_error, color="black", linestyle="--", linewidth=1, label=bound)
    if low > 0.0 and high / low > 20.0:
        ax.set_xscale("log")
    ax.set_ylim(0.0, 1.02)
    ax.set_xlabel(f"largest |q_r - q| over joints from t = {robustness.after:g} s on (rad)")
    ax.set_ylabel("fraction of runs within x")
    ax.set_title("runs within a tracking bound (stopped runs never are)")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out / "robustness.png", dpi=110)
    return "robustness.png"


def plot_robustness_by_parameter(
    out: Path, controllers: list[str], finished: list[dict], varying: list[str], robustness: Robustness
) -> str | None:
    """robustness_by_parameter.png: one panel per swept parameter, the largest |q_r - q| from
    ``after`` on of every finished run against the parameter's value (runs that stopped as
    crosses above the rest), and the bound; returns the file name (None if nothing to plot)."""
    plt = _pyplot()

    if not varying or not finished:
        return None
    points = [(row, assess(row["record"], robustness)) for row in finished]
    errors = [v["steady_max_error"] for _, v in points if v["stopped"] is None and math.isfinite(v["steady_max_error"])]
    top = max([*errors, robustness.max_error]) * 1.25  # where runs that stopped are drawn
    columns = min(3, len(varying))
    rows_count = math.ceil(len(varying) / columns)
    fig, axes = plt.subplots(rows_count, columns, figsize=(4.2 * columns, 3.3 * rows_count), squeeze=False)
    for ax, key in zip(axes.ravel(), varying):
        values = [row["params"][key] for row, _ in points]
        numeric = all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in values)
        labels = [] if numeric else unique([value_label(v) for v in values])
        for c, name in enumerate(controllers):
            mine = [(row, v) for row, v in points if row["controller"] == name]
            xs = [row["params"][key] if numeric else labels.index(value_label(row["params"][key])) for row, _ in mine]
            ran = [(x, v["steady_max_error"]) for x, (_, v) in zip(xs, mine) if v["stopped"] is None]
            stopped = [x for x, (_, v) in zip(xs, mine) if v["stopped"] is not None]
            colour = _colour(name)
            ax.scatter([x for x, _ in ran], [y for _, y in ran], s=10, alpha=0.6, color=colour, label=name)
            if stopped:
                ax.scatter(stopped, [top * (1.0 + 0.04 * c)] * len(stopped), s=18, marker="x", color=colour)
        if not numeric:
            ax.set_xticks(range(len(labels)), [_short(label) for label in labels], rotation=20)
        ax.axhline(robustness.max_error, color="black", linestyle="--", linewidth=1)
        ax.set_xlabel(key)
        ax.set_ylabel(f"max |q_r - q| after {robustness.after:g} s (rad)", fontsize=8)
        ax.grid(True, alpha=0.3)
    for ax in axes.ravel()[len(varying) :]:
        ax.axis("off")
    axes[0, 0].legend(fontsize=7)
    fig.suptitle(
        f"largest error after {robustness.after:g} s per run; dashed: bound {robustness.max_error:g} rad; "
        "crosses at the top: runs that stopped (one row per controller)",
        fontsize=9,
    )
    fig.tight_layout()
    fig.savefig(out / "robustness_by_parameter.png", dpi=110)
    return "robustness_by_parameter.png"


def _grouped_boxes(ax, key: str, controllers: list[str], finished: list[dict], values, label: str) -> None:
    """Boxes of the metric per value of ``key``, one colour per controller."""
    labels = unique([value_label(r["params"][key]) for r in finished])
    width = 0.8 / max(1, len(controllers))
    for c, name in enumerate(controllers):
        data, positions = [], []
        for g, value in enumerate(labels):
            group = values([r for r in finished if r["controller"] == name and value_label(r["params"][key]) == value])
            if group:
                data.append(group)
                positions.append(g + (c - (len(controllers) - 1) / 2) * width)
        if not data:
            continue
        box = ax.boxplot(
            data,
            positions=positions,
            widths=width * 0.9,
            patch_artist=True,
            medianprops={"color": "black"},
            manage_ticks=False,
        )
        for patch in box["boxes"]:
            patch.set_facecolor(_colour(name, "lightgrey"))
            patch.set_alpha(0.5)
        ax.plot([], [], color=_colour(name, "grey"), linewidth=8, alpha=0.5, label=name)
    ax.set_xticks(range(len(labels)), [_short(value) for value in labels], rotation=20 if len(labels) > 4 else 0)
    ax.set_xlabel(key)
    ax.set_ylabel(label)
    ax.set_title(f"by {key}")
    ax.grid(True, axis="y", alpha=0.3)
    ax.legend(fontsize=8)


def _short(label: str) -> str:
    """File arms by their file name; long labels cut."""
    if "/" in label or "\\" in label:
        label = Path(label).name
    return label if len(label) <= 24 else label[:21] + "..."
