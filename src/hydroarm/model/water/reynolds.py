"""Morison drag with a Reynolds-dependent coefficient: a water a constant-C_d learner does not share.

With ``Water.drag_model = "reynolds"`` the drag coefficient varies along every strip of every
wetted cylinder with the local Reynolds number of the normal flow::

    Re(s) = |v_n(s)| D / nu,      f_d(s) = -1/2 rho C_d(Re(s)) kappa(L/D) D |v_n(s)| v_n(s)

``C_d(Re)``: the steady-flow drag coefficient of a smooth circular cylinder, the curve of
DNV-RP-C205 (Environmental conditions and environmental loads), section 6.7, Fig. 6-6, as points
read from the figure (:data:`LOG_RE`, :data:`CD_SMOOTH`; linear in log10 Re between them, held
constant beyond the ends): about 1.0-1.2 in the subcritical range, the drag crisis near
Re = 3-5e5 (down to about 0.3), then the smooth post-critical value 0.65 by Re = 1e7.
``kappa(L/D)``: the reduction factor of a cylinder of finite length L/D (flow round its free
ends), the same section's table (:data:`ASPECT_RATIO`, :data:`ASPECT_FACTOR`; linear between
entries, 1 for an infinitely long cylinder). The water's own ``cd`` is not used then (a
cylinder's ``cd`` override in the arm file neither): the curve is the drag.

The points are read from a figure: they reproduce its shape (plateau, crisis, recovery), not
three significant digits. The integrand is no longer a polynomial in s times ``|v_n| v_n``, so
each piece between the kink of ``|v_n|`` and the ends is integrated by the water's Gauss-Legendre
rule as before, C_d evaluated at every node: the same strip loop and drag as the constant C_d
(:func:`hydroarm.model.water.effects.drag`, ``Strips.drag_model`` = 1), with the per-cylinder
``1/2 rho D kappa(L/D)`` of :class:`~hydroarm.model.water.strips.StripGeometry`.
"""

from __future__ import annotations

import numba
import numpy as np

LOG_RE = np.array([1.0, 2.0, 3.0, 4.0, 5.0, 5.3, 5.5, 5.7, 6.0, 6.5, 7.0])
"""log10 Re of the points of the smooth-cylinder curve."""

CD_SMOOTH = np.array([2.8, 1.4, 1.0, 1.1, 1.2, 1.2, 0.6, 0.3, 0.4, 0.55, 0.65])
"""C_d of a smooth circular cylinder in steady flow at :data:`LOG_RE` (DNV-RP-C205 Fig. 6-6, read
from the figure)."""

ASPECT_RATIO = np.array([2.0, 5.0, 10.0, 20.0, 40.0, 50.0, 100.0, 1e4])
ASPECT_FACTOR = np.array([0.58, 0.62, 0.68, 0.74, 0.82, 0.87, 0.98, 1.0])
"""kappa(L/D), the reduction factor of a finite cylinder's drag (DNV-RP-C205 section 6.7)."""


def drag_coefficient(reynolds: np.ndarray | float) -> np.ndarray:
    """C_d(Re) of a smooth circular cylinder (module docstring); Re <= 0 gives the low-Re end."""
    log_re = np.log10(np.maximum(np.asarray(reynolds, dtype=float), 1e-300))
    return np.interp(log_re, LOG_RE, CD_SMOOTH)


def aspect_factor(length_over_diameter: np.ndarray | float) -> np.ndarray:
    """kappa(L/D) (module docstring); L/D below 2 takes the factor of 2."""
    return np.interp(np.asarray(length_over_diameter, dtype=float), ASPECT_RATIO, ASPECT_FACTOR)


@numba.njit(cache=True, inline="always")
def interpolate(x, table, row_x, row_y, count):  # pragma: no cover - compiled
    """Linear interpolation at x of the ``count`` points (``table[row_x, i]``, ``table[row_y, i]``),
    held constant beyond the ends (the compiled :func:`numpy.interp`; the drag of
    :mod:`hydroarm.model.water.effects` evaluates :data:`CD_SMOOTH` with it at every Gauss node, from
    the rows of its frame)."""
    if x <= table[row_x, 0]:
        return table[row_y, 0]
    last = count - 1
    if x >= table[row_x, last]:
        return table[row_y, last]
    i = 0
    while table[row_x, i + 1] < x:
        i += 1
    w = (x - table[row_x, i]) / (table[row_x, i + 1] - table[row_x, i])
    return table[row_y, i] + w * (table[row_y, i + 1] - table[row_y, i])
