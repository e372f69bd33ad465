"""The browser viewer's time series as inline SVG, with a time cursor.

Each chart is one ``<svg>`` with a ``viewBox`` and ``width="100%"``: the browser lays it out at
its container's width in the same pass that inserts it, so it is drawn at its real width in
the first painted frame (a one-shot headless screenshot included). A canvas chart (uPlot, as
viser draws one) is created at width 0 and sized only after a resize observer and an animation
frame have run, which a headless screenshot does not wait for.

Every chart shares one horizontal geometry (:data:`LEFT`, :data:`PLOT_WIDTH`) and the run's
time span, so one CSS variable places the time cursor of all of them: ``--hydroarm-cursor-x``,
the cursor's offset in viewBox units from the plot's left edge (:meth:`Chart.cursor_offset`). The
live viewer sets it with a ``<style>`` rule each time it shows a sample; the recording's script
sets it from the playback bar's time. No plotting library is imported (the viewer starts
without matplotlib).
"""

from __future__ import annotations

import html
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from hydroarm.model.arm.description import Arm
from hydroarm.sim.runner import Trajectory
from hydroarm.studies.playback import VehicleMotion

# tab10 (the colours of animate.LINK_COLOURS), RGB 0-255: link j's colour is LINK_RGB[(j - 1) % 8]
LINK_RGB = (
    (31, 119, 180), (255, 127, 14), (44, 160, 44), (214, 39, 40),
    (148, 103, 189), (140, 86, 75), (227, 119, 194), (188, 189, 34),
)  # fmt: skip
AXIS_COLOURS = ("rgb(214,39,40)", "rgb(44,160,44)", "rgb(31,119,180)")  # x, y, z as viser's axes
WIDTH = 400.0  # viewBox width of every chart
LEFT, RIGHT, TOP = 48.0, 12.0, 26.0  # margins (viewBox units): y tick labels, right edge, title
PLOT_WIDTH = WIDTH - LEFT - RIGHT
PLOT_HEIGHT = 150.0
AXIS_LABELS = 18.0  # the x tick labels under the plot
LEGEND_ROW, LEGEND_SLOT = 15.0, 85.0  # legend row height and width of one entry
MOST_POINTS = int(2 * PLOT_WIDTH)  # more samples than this are decimated to a min and a max per viewBox unit
CURSOR_VARIABLE = "--hydroarm-cursor-x"
FONT = "font-family:system-ui,-apple-system,'Segoe UI',Roboto,sans-serif"


@dataclass(frozen=True)
class Series:
    """One line of a chart: ``values`` (K,) against the chart's time, its ``label`` and CSS
    ``colour``; ``dash``: an SVG dash pattern ("" for solid); ``legend``: whether the legend lists
    it. Non-finite values leave gaps."""

    label: str
    values: np.ndarray
    colour: str
    dash: str = ""
    legend: bool = True


@dataclass(frozen=True)
class Band:
    """A filled region between ``lower`` and ``upper`` (K,) (e.g. a +-2 sigma band), in the legend as ``label``."""

    label: str
    lower: np.ndarray
    upper: np.ndarray
    colour: str


def nice_ticks(low: float, high: float, count: int = 5) -> np.ndarray:
    """Round tick values within [low, high] spaced 1, 2 or 5 times a power of ten apart: the
    spacing whose number of ticks is nearest ``count`` (the wider one on a tie)."""
    if not (math.isfinite(low) and math.isfinite(high)) or high <= low:
        return np.array([low]) if math.isfinite(low) else np.array([])
    power = 10.0 ** math.floor(math.log10((high - low) / max(count, 1)))
    best = None
    for step in (m * power for m in (1.0, 2.0, 5.0, 10.0, 20.0)):
        ticks = np.arange(math.ceil(low / step - 1e-9) * step, high + step * 1e-9, step)
        if best is None or abs(len(ticks) - count) <= abs(len(best) - count):
            best = ticks
    return np.where(np.abs(best) < (high - low) * 1e-12, 0.0, best)


def _labels(ticks: np.ndarray) -> list[str]:
    """Tick labels with as many decimals as the ticks' spacing needs."""
    step = float(ticks[1] - ticks[0]) if len(ticks) > 1 else 1.0
    digits = max(0, -math.floor(math.log10(step) + 1e-9)) if step > 0 else 0
    return [f"{v:.{digits}f}" if abs(v) < 1e5 else f"{v:.3g}" for v in ticks]


def _y_range(values: list[np.ndarray]) -> tuple[float, float]:
    """The y range holding every finite value, with 5 % margins (a constant gets +-half its size, at least 0.5)."""
    finite = np.concatenate([np.asarray(v, dtype=float).ravel() for v in values]) if values else np.array([])
    finite = finite[np.isfinite(finite)]
    low, high = (float(finite.min()), float(finite.max())) if finite.size else (-1.0, 1.0)
    if high - low <= 1e-12 * max(1.0, abs(high)):
        half = max(0.5, 0.5 * abs(high))
        return low - half, high + half
    pad = 0.05 * (high - low)
    return low - pad, high + pad


def _columns(count: int) -> np.ndarray | None:
    """Edges (C + 1,) of the ``MOST_POINTS / 2`` columns ``count`` samples are split into (None: keep every sample)."""
    if count <= MOST_POINTS:
        return None
    return np.linspace(0, count, MOST_POINTS // 2 + 1).astype(int)


def _decimate(values: np.ndarray, edges: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """(sample indices, values) to draw: every sample, or each column's min and max in time order
    (a column of non-finite values keeps one, a gap)."""
    if edges is None:
        return np.arange(len(values)), values
    column = np.repeat(np.arange(len(edges) - 1), np.diff(edges))
    finite = np.isfinite(values)
    lowest = np.lexsort((np.where(finite, values, np.inf), column))[edges[:-1]]
    highest = np.lexsort((np.where(finite, -values, np.inf), column))[edges[:-1]]
    index = np.unique(np.concatenate([lowest, highest]))
    return index, values[index]


def _runs(finite: np.ndarray) -> list[tuple[int, int]]:
    """(start, stop) of each run of consecutive True in ``finite``."""
    edges = np.flatnonzero(np.diff(np.concatenate([[0], finite.astype(np.int8), [0]])))
    return list(zip(edges[0::2], edges[1::2]))


def _points(x: np.ndarray, y: np.ndarray) -> str:
    return " ".join(f"{a:.1f},{b:.1f}" for a, b in zip(x, y))


class Chart:
    """A time-series chart of a run: ``t`` (K,) s, the x axis of every series.

    :meth:`svg` draws the given series (and band) with their y range, ticks, a title, a legend
    and the time cursor.
    """

    def __init__(self, t: np.ndarray):
        self.t = np.asarray(t, dtype=float)
        self.t0 = float(self.t[0])
        span = float(self.t[-1] - self.t[0])
        self.span = span if span > 0.0 else 1.0
        self.edges = _columns(len(self.t))

    def x(self, t: np.ndarray | float) -> np.ndarray:
        """The viewBox x of times ``t`` (s)."""
        return LEFT + (np.asarray(t, dtype=float) - self.t0) / self.span * PLOT_WIDTH

    def svg(self, key: str, title: str, series: Sequence[Series], band: Band | None = None) -> str:
        """The chart as an ``<svg class="hydroarm-chart" data-chart=key>`` string; ``key``: unique on the page."""
        low, high = _y_range([s.values for s in series] + ([band.lower, band.upper] if band is not None else []))
        bottom = TOP + PLOT_HEIGHT

        def y(v: np.ndarray | float) -> np.ndarray:
            return TOP + (high - np.asarray(v, dtype=float)) / (high - low) * PLOT_HEIGHT

        entries = [(s.label, s.colour, s.dash) for s in series if s.legend]
        entries += [(band.label, band.colour, "")] if band is not None else []
        per_row = max(1, int(PLOT_WIDTH // LEGEND_SLOT))
        height = bottom + AXIS_LABELS + -(-len(entries) // per_row) * LEGEND_ROW + 4.0
        box = f'x="{LEFT:g}" y="{TOP:g}" width="{PLOT_WIDTH:g}" height="{PLOT_HEIGHT:g}"'
        out = [
            f'<svg class="hydroarm-chart" data-chart="{key}" viewBox="0 0 {WIDTH:g} {height:g}" width="100%" '
            f'role="img" aria-label="{html.escape(title)}" style="display:block;{FONT};font-size:11px">',
            f'<clipPath id="hydroarm-clip-{key}"><rect {box}/></clipPath>',
            f'<text x="{WIDTH / 2:g}" y="{TOP - 9:g}" text-anchor="middle" font-size="12" font-weight="600">'
            f"{html.escape(title)}</text>",
            f'<rect {box} fill="none" stroke="#bbb"/>',
        ]
        y_ticks = nice_ticks(low, high)
        for value, text in zip(y_ticks, _labels(y_ticks)):
            yy = float(y(value))
            out.append(f'<line x1="{LEFT:g}" x2="{LEFT + PLOT_WIDTH:g}" y1="{yy:.1f}" y2="{yy:.1f}" stroke="#eee"/>')
            out.append(f'<text x="{LEFT - 4:g}" y="{yy + 3.5:.1f}" text-anchor="end" fill="#555">{text}</text>')
        x_ticks = nice_ticks(self.t0, self.t0 + self.span, 6)
        for value, text in zip(x_ticks, _labels(x_ticks)):
            xx = float(self.x(value))
            out.append(f'<line x1="{xx:.1f}" x2="{xx:.1f}" y1="{TOP:g}" y2="{bottom:g}" stroke="#eee"/>')
            out.append(f'<text x="{xx:.1f}" y="{bottom + 13:g}" text-anchor="middle" fill="#555">{text}</text>')
        out.append(f'<text x="{LEFT - 12:g}" y="{bottom + 13:g}" text-anchor="end" fill="#555">t (s)</text>')
        out.append(f'<g clip-path="url(#hydroarm-clip-{key})" fill="none" stroke-linejoin="round">')
        if band is not None:
            out += self._band(band, y)
        for s in series:
            out += self._line(s, y)
        out.append("</g>")
        if not any(np.isfinite(v).any() for v in [s.values for s in series]):
            out.append(
                f'<text x="{LEFT + PLOT_WIDTH / 2:g}" y="{TOP + PLOT_HEIGHT / 2:g}" text-anchor="middle" '
                'fill="#888">not recorded in this run</text>'
            )
        out.append(
            f'<line class="hydroarm-cursor" x1="{LEFT:g}" x2="{LEFT:g}" y1="{TOP:g}" y2="{bottom:g}" '
            f'stroke="#111" stroke-width="1.2" style="transform:translateX(var({CURSOR_VARIABLE},0px))"/>'
        )
        for i, (label, colour, dash) in enumerate(entries):
            x0 = LEFT + (i % per_row) * LEGEND_SLOT
            y0 = bottom + AXIS_LABELS + (i // per_row) * LEGEND_ROW + 8.0
            pattern = f' stroke-dasharray="{dash}"' if dash else ""
            out.append(
                f'<line x1="{x0:g}" x2="{x0 + 14:g}" y1="{y0 - 3.5:g}" y2="{y0 - 3.5:g}" stroke="{colour}" '
                f'stroke-width="3"{pattern}/><text x="{x0 + 18:g}" y="{y0:g}">{html.escape(label)}</text>'
            )
        out.append("</svg>")
        return "".join(out)

    def _line(self, series: Series, y) -> list[str]:
        values = np.asarray(series.values, dtype=float)
        if np.all(np.isfinite(values)) and np.ptp(values) == 0.0:  # a constant (a limit): its two ends
            index, values = np.array([0, len(values) - 1]), values[[0, -1]]
        else:
            index, values = _decimate(values, self.edges)
        xs, ys = self.x(self.t[index]), y(values)
        segments = [f"M{_points(xs[a:b], ys[a:b])}" for a, b in _runs(np.isfinite(values))]
        if not segments:
            return []
        dash = f' stroke-dasharray="{series.dash}"' if series.dash else ""
        return [f'<path d="{" ".join(segments)}" stroke="{series.colour}" stroke-width="1.4"{dash}/>']

    def _band(self, band: Band, y) -> list[str]:
        index, _ = _decimate(0.5 * (band.lower + band.upper), self.edges)
        lower, upper, xs = band.lower[index], band.upper[index], self.x(self.t[index])
        out = []
        for a, b in _runs(np.isfinite(lower) & np.isfinite(upper)):
            ring = np.concatenate([np.arange(a, b), np.arange(b - 1, a - 1, -1)])
            ys = np.concatenate([y(upper[a:b]), y(lower[a:b])[::-1]])
            out.append(f'<polygon points="{_points(xs[ring], ys)}" fill="{band.colour}" stroke="none"/>')
        return out

    def cursor_offset(self, time_s: float) -> float:
        """The cursor's offset (viewBox units) from the plot's left edge at ``time_s`` (s), held within the plot."""
        return float(np.clip((time_s - self.t0) / self.span, 0.0, 1.0) * PLOT_WIDTH)


def cursor_style(offset: float) -> str:
    """A ``<style>`` element placing every chart's cursor ``offset`` viewBox units right of the plot's left edge."""
    return f"<style>:root{{{CURSOR_VARIABLE}:{offset:.2f}px}}</style>"


def _rgb(colour: tuple[int, int, int]) -> str:
    return "rgb({},{},{})".format(*colour)


class RunCharts:
    """The charts of one run: the joint errors, one joint's torque against its limit and its
    disturbance against the controller's estimate (+-2 sigma), and on a vehicle run the base's
    drift from the target and its attitude. Each method returns one chart's SVG (:class:`Chart`)."""

    def __init__(self, traj: Trajectory, arm: Arm, vehicle: VehicleMotion | None = None):
        self.traj, self.vehicle = traj, vehicle
        limit = traj.meta.get("settings", {}).get("torque_limit")  # the limit the run held, if it set one
        self.torque_limit = np.asarray(arm.with_torque_limit(limit).torque_limit, dtype=float)
        self.chart = Chart(traj.t)
        self.n = traj.n_joints

    def errors(self) -> str:
        """The joint errors ``q_r - q`` (rad), one line per joint."""
        error = self.traj.q_ref - self.traj.q
        series = [Series(f"joint {j + 1}", error[:, j], _rgb(LINK_RGB[j % 8])) for j in range(self.n)]
        return self.chart.svg("error", "joint error q_r - q (rad)", series)

    def torque(self, j: int) -> str:
        """Joint ``j``'s torque (N m) against its limit (dashed; none when unlimited)."""
        u = self.traj.u[:, j]
        series = [Series("torque", u, "rgb(31,119,180)")]
        limit = float(self.torque_limit[j])
        if math.isfinite(limit):
            series.append(Series("+-limit", np.full_like(u, limit), "rgb(214,39,40)", "4 3"))
            series.append(Series("-limit", np.full_like(u, -limit), "rgb(214,39,40)", "4 3", legend=False))
        return self.chart.svg(f"torque-{j + 1}", f"joint {j + 1}: torque u (N m) against its limit", series)

    def disturbance(self, j: int) -> str:
        """Joint ``j``'s true disturbance (N m) against the controller's estimate and its +-2 sigma band."""
        traj = self.traj
        mean = traj.disturbance_estimate[:, j]
        sigma = np.sqrt(np.maximum(traj.disturbance_var[:, j], 0.0))
        series = [Series("true", traj.disturbance[:, j], "rgb(0,0,0)"), Series("estimate", mean, "rgb(255,127,14)")]
        band = Band("+-2 sigma", mean - 2.0 * sigma, mean + 2.0 * sigma, "rgba(255,127,14,0.2)")
        return self.chart.svg(
            f"disturbance-{j + 1}", f"joint {j + 1}: disturbance (N m), true vs estimate", series, band
        )

    def drift(self) -> str:
        """The vehicle base's offset from the station-keeping target (mm), per world axis."""
        offset = 1e3 * self.vehicle.drift()
        series = [Series(axis, offset[:, i], AXIS_COLOURS[i]) for i, axis in enumerate("xyz")]
        return self.chart.svg("drift", f"{self.vehicle.name}: drift from the target (mm)", series)

    def attitude(self) -> str:
        """The vehicle base's roll, pitch and yaw (deg)."""
        angles = self.vehicle.attitude_deg()
        series = [Series(name, angles[:, i], AXIS_COLOURS[i]) for i, name in enumerate(("roll", "pitch", "yaw"))]
        return self.chart.svg("attitude", f"{self.vehicle.name}: attitude (deg)", series)
