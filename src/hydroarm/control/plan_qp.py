"""The horizon QP of the torque limits, solved on its structure: a compiled dual active set.

The problem of :class:`~hydroarm.control.idmpc_limits.HorizonQP` (the IDMPC's ``limits = "qp"``
and PI-IDMPC's planner), in the stacked moves U (N n,), step-major (``U[k n + j]``)::

    min 1/2 U' H U + g' U    s.t.  lower <= R U <= upper

has two structures a dense solver (DAQP) does not see:

- H is constant (it depends on the weights only) and block diagonal per joint: ``H_j`` (N, N),
  so its Cholesky factors ``H_j = L_j L_j'`` are computed once (:func:`joint_factors`), not at
  every solve;
- R (the torque rows) is block lower triangular in time (row block k touches the moves of steps
  0..k only), so ``R U`` costs half a dense product.

With ``x = L' U`` (per joint) the problem is the least-distance problem
``min 1/2 ||x + d||^2, lower <= M x <= upper`` with ``d = L^-1 g``, ``M = R L^-T``, solved by the
dual active set of DAQP (Arnstrom, Bemporad, Axehill 2022): ``x = -d - M_A' lambda_A`` for the
working set A; ``lambda_A`` from the Cholesky factor of ``M_A M_A'``, appended one row per added
constraint, and downdated by Givens rotations when one is removed; the most violated constraint joins while the
multipliers have their signs (``lambda >= 0`` at an upper bound, ``<= 0`` at a lower), else a
step to the first sign change removes that one. A row of M is formed only when its constraint
joins. The tolerances are DAQP's defaults (a constraint violated by at most ``primal_tol`` N m
does not join; a multiplier within ``dual_tol`` of zero keeps its sign), so both solvers stop at
the same working set and agree to rounding (tests/test_plan_qp.py: 1e-9 against DAQP on the
planner's problems and random ones, and SciPy as an independent oracle).

With the drives' rate rows (issue 32) the rows are 2 N n: below the torque rows their
differences ``R_k - R_{k-1}`` (row block k less block k - 1), block lower triangular too, formed
here from R when a row joins (its whitened row) or is checked (its value from the torque rows'),
never as a dense copy. The working set stays at most N n rows: a joining row dependent on it
(a rate row with both its torque rows active) first takes a member's place by Goldfarb and
Idnani's step in the dual, and the final multipliers get :data:`REFINEMENTS` steps of iterative
refinement (the Gram matrix of such working sets reaches condition numbers of 1e13). The torque
rows alone run the same arithmetic as before the rate rows (the same bits).

Every kernel is a fixed-order loop (numba, no BLAS): the same bits on every machine.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from hydroarm.model.dynamics.fixed_order import cholesky_factor, cholesky_substitute, forward_substitute

PRIMAL_TOL = 1e-6
"""A constraint violated by at most this (N m, the rows' unit) does not join (DAQP's default)."""
DUAL_TOL = 1e-12
"""A multiplier within this of zero keeps its sign (DAQP's default)."""
SOLVED, INFEASIBLE, ITERATION_LIMIT = 1, -1, -4
"""Exit flags, as DAQP's: 1 optimal, -1 primal infeasible, -4 iteration limit."""
REFINEMENTS = 2
"""Steps of iterative refinement (:func:`_refine`) of a rate-limited solve's final multipliers."""
DEPENDENT_TOL = 1e-10
"""A joining row whose squared pivot in the working set's Gram factor is at most this fraction of
its squared norm is taken as dependent on the working set (the rate rows only: a rate row is the
difference of two torque rows)."""


@numba.njit(cache=True)
def joint_factors(hessian, n):  # pragma: no cover - compiled
    """The Cholesky factors ``L_j`` (n, N, N), lower, of the per-joint blocks of ``hessian``
    (N n, N n), step-major (joint j's block: rows and columns ``k n + j``;
    :func:`~hydroarm.model.dynamics.fixed_order.cholesky_factor`). A block that is not positive
    definite raises."""
    horizon = hessian.shape[0] // n
    factors = np.zeros((n, horizon, horizon))
    for j in range(n):
        if not cholesky_factor(hessian[j::n, j::n], factors[j]):
            raise ValueError("a joint's block of the Hessian is not positive definite")
    return factors


@numba.njit(cache=True)
def _moves(factors, x, moves):  # pragma: no cover - compiled
    """``U = L^-T x`` per joint: x (n, N) whitened, moves (N n,) step-major."""
    n, horizon = x.shape[0], x.shape[1]
    for j in range(n):
        factor = factors[j]
        for r in range(horizon - 1, -1, -1):
            total = x[j, r]
            for i in range(r + 1, horizon):
                total -= factor[i, r] * moves[i * n + j]
            moves[r * n + j] = total / factor[r, r]


@numba.njit(cache=True)
def _row(factors, rows, r, out, work_in, work_out):  # pragma: no cover - compiled
    """Row r of ``M = R L^-T``, whitened, into out (n, N): per joint ``L_j^-1 R[r, joint j]'``.
    A row ``r >= N n`` is a rate row: torque row ``r - N n`` less the one a step before it
    (:func:`solve_plan_qp`), formed here from the torque rows."""
    n, horizon = factors.shape[0], factors.shape[1]
    size = n * horizon
    torque = r - size if r >= size else r
    last = torque // n  # row block k touches the moves of steps 0..k
    before = torque - n if r >= size and torque >= n else -1
    for j in range(n):
        for k in range(horizon):
            if k > last:
                work_in[k] = 0.0
            elif before >= 0:
                work_in[k] = rows[torque, k * n + j] - rows[before, k * n + j]
            else:
                work_in[k] = rows[torque, k * n + j]
        forward_substitute(factors[j], work_in, work_out)
        for k in range(horizon):
            out[j, k] = work_out[k]


@numba.njit(cache=True)
def _refactor(gram, size, chol):  # pragma: no cover - compiled
    """The Cholesky factor of ``gram[:size, :size]`` into chol."""
    for r in range(size):
        for c in range(r + 1):
            total = gram[r, c]
            for i in range(c):
                total -= chol[r, i] * chol[c, i]
            if r == c:
                chol[r, r] = math.sqrt(max(total, 1e-300))
            else:
                chol[r, c] = total / chol[c, c]


@numba.njit(cache=True)
def _drop_row(chol, size, p):  # pragma: no cover - compiled
    """The Cholesky factor of ``M_A M_A'`` without row p of M_A, in place (``size`` - 1 rows):
    row p removed, the superdiagonal it leaves zeroed by Givens rotations of adjacent columns
    (O(size^2), not a new factorisation)."""
    for i in range(p, size - 1):
        for c in range(i + 2):
            chol[i, c] = chol[i + 1, c]
    for j in range(p, size - 1):
        a, b = chol[j, j], chol[j, j + 1]
        radius = math.sqrt(a * a + b * b)
        cos, sin = a / radius, b / radius
        for i in range(j, size - 1):
            x, y = chol[i, j], chol[i, j + 1]
            chol[i, j] = cos * x + sin * y
            chol[i, j + 1] = -sin * x + cos * y
        chol[j, j + 1] = 0.0


@numba.njit(cache=True)
def _whiten(factors, gradient, d, work_in, work_out):  # pragma: no cover - compiled
    """d (n, N): each joint's gradient through its factor's forward substitution (:func:`_forward`)."""
    n, horizon = d.shape
    for j in range(n):
        for k in range(horizon):
            work_in[k] = gradient[k * n + j]
        forward_substitute(factors[j], work_in, work_out)
        for k in range(horizon):
            d[j, k] = work_out[k]


@numba.njit(cache=True)
def _gram_row(m_rows, count, gram):  # pragma: no cover - compiled
    """Row and column ``count`` of the working set's Gram matrix M_A M_A' (in place)."""
    n, horizon = m_rows.shape[1], m_rows.shape[2]
    for p in range(count + 1):
        total = 0.0
        for j in range(n):
            for k in range(horizon):
                total += m_rows[count, j, k] * m_rows[p, j, k]
        gram[count, p] = total
        gram[p, count] = total


@numba.njit(cache=True)
def _append_cholesky(gram, chol, count):  # pragma: no cover - compiled
    """Row ``count`` of the Cholesky factor of the Gram matrix, the rows above it unchanged."""
    for p in range(count):
        total = gram[count, p]
        for i in range(p):
            total -= chol[count, i] * chol[p, i]
        chol[count, p] = total / chol[p, p]
    total = gram[count, count]
    for i in range(count):
        total -= chol[count, i] * chol[count, i]
    chol[count, count] = math.sqrt(max(total, 1e-300))


@numba.njit(cache=True)
def _member_target(m_row, bound, d):  # pragma: no cover - compiled
    """A working-set row's entry of ``-(b_A + M_A d)`` (:func:`_unconstrained_multipliers`): fixed
    while it is a member (d does not change within a solve), so computed once as it joins."""
    n, horizon = d.shape
    total = bound
    for j in range(n):
        for k in range(horizon):
            total += m_row[j, k] * d[j, k]
    return -total


@numba.njit(cache=True)
def _unconstrained_multipliers(chol, count, target, star):  # pragma: no cover
    """``star`` = lambda* = -(M_A M_A')^-1 (b_A + M_A d) of the working set (in place), on the Gram
    matrix's factor ``chol`` (:func:`~hydroarm.model.dynamics.fixed_order.cholesky_substitute`);
    ``target`` holds each member's ``-(b_r + m_r d)`` (:func:`_member_target`)."""
    cholesky_substitute(chol[:count, :count], target[:count], star[:count])


@numba.njit(cache=True)
def _primal_and_most_violated(
    factors, rows, upper, lower, sign, m_rows, lam, d, count, primal_tol, x, moves, slack
):  # pragma: no cover - compiled
    """The primal point of the working set's multipliers (x = -d - M_A' lam, the moves U = L^-T x,
    the rows R U into ``slack``) and the most violated row off the working set (-1: none beyond
    ``primal_tol``)."""
    n, horizon = d.shape
    for j in range(n):
        for k in range(horizon):
            x[j, k] = -d[j, k]
    for p in range(count):  # each x[j, k] sums its terms in the same order, the rows read contiguously
        weight = lam[p]
        for j in range(n):
            for k in range(horizon):
                x[j, k] -= m_rows[p, j, k] * weight
    _moves(factors, x, moves)
    size = moves.shape[0]
    for r in range(size):
        last = (r // n + 1) * n
        total = 0.0
        for i in range(last):
            total += rows[r, i] * moves[i]
        slack[r] = total
    for r in range(size, slack.shape[0]):  # the rate rows: differences of consecutive torque rows
        torque = r - size
        slack[r] = slack[torque] - slack[torque - n] if torque >= n else slack[torque]
    worst = -1
    violation = primal_tol
    for r in range(slack.shape[0]):
        if sign[r] != 0:
            continue
        total = slack[r]
        if total - upper[r] > violation:
            violation, worst = total - upper[r], r
        elif lower[r] - total > violation:
            violation, worst = lower[r] - total, r
    return worst


@numba.njit(cache=True)
def _load_working_set(factors, rows, warm, bounds, active, sign, m_rows, gram, target, work):  # pragma: no cover
    """The warm working set's rows (``warm``: +1 upper, -1 lower, 0 free) into ``active``,
    ``sign``, ``m_rows``, the Gram matrix and ``target`` (:func:`_member_target`; ``bounds`` =
    (upper, lower, d), ``work`` = (work_in, work_out)); their count."""
    upper, lower, d = bounds
    count = 0
    for r in range(warm.shape[0]):
        if warm[r] != 0:
            active[count] = r
            sign[r] = 1 if warm[r] > 0 else -1
            _row(factors, rows, r, m_rows[count], work[0], work[1])
            _gram_row(m_rows, count, gram)
            target[count] = _member_target(m_rows[count], upper[r] if sign[r] > 0 else lower[r], d)
            count += 1
    return count


@numba.njit(cache=True)
def _load_independent(factors, rows, warm, bounds, active, sign, m_rows, gram, chol, target, work):  # pragma: no cover
    """:func:`_load_working_set` with the rate rows: the Gram matrix's factor appended row by row,
    and a warm row dependent on those before it (:func:`_dependent`) left out; their count."""
    upper, lower, d = bounds
    count = 0
    for r in range(warm.shape[0]):
        if warm[r] == 0 or count == m_rows.shape[0]:
            continue
        _row(factors, rows, r, m_rows[count], work[0], work[1])
        _gram_row(m_rows, count, gram)
        _append_cholesky(gram, chol, count)
        if _dependent(gram, chol, count):
            continue
        active[count] = r
        sign[r] = 1 if warm[r] > 0 else -1
        target[count] = _member_target(m_rows[count], upper[r] if sign[r] > 0 else lower[r], d)
        count += 1
    return count


@numba.njit(cache=True)
def _dependent(gram, chol, count):  # pragma: no cover - compiled
    """Whether row ``count`` of the working set is (to rounding) a combination of the rows before
    it: its pivot in the Gram matrix's factor below DEPENDENT_TOL of its norm (relative, squared)."""
    return chol[count, count] * chol[count, count] <= DEPENDENT_TOL * gram[count, count]


@numba.njit(cache=True)
def _drop(active, sign, lam, target, m_rows, chol, count, p):  # pragma: no cover - compiled
    """Working-set member p leaves (its sign 0, the order of the others kept); the new count."""
    sign[active[p]] = 0
    for i in range(p, count - 1):
        active[i] = active[i + 1]
        lam[i] = lam[i + 1]
        target[i] = target[i + 1]
        m_rows[i] = m_rows[i + 1]
    _drop_row(chol, count, p)
    return count - 1


@numba.njit(cache=True)
def _make_room(active, sign, lam, target, m_rows, gram, chol, count, joining, mu, dual_tol):  # pragma: no cover
    """A joining row (sign ``joining``, whitened in ``m_rows[count]``, its Gram row computed) that
    is a combination ``M_A' mu`` of the working set's rows (the rate row k of torque rows k and
    k - 1): Goldfarb and Idnani's step in the dual. Its multiplier grows by t (with its sign) and
    the working set's by ``-t joining mu``, the primal point unchanged, until the first working-set
    multiplier reaches zero; that one leaves and the joining row takes t. Returns ``(count, t)``,
    count -1: no member blocks (the problem is infeasible)."""
    for p in range(count):
        mu[p] = gram[count, p]
    cholesky_substitute(chol[:count, :count], mu[:count], mu[:count])
    blocking = -1
    step = 0.0
    for p in range(count):
        toward = joining * mu[p]
        if sign[active[p]] * toward > dual_tol:
            t = lam[p] / toward
            if blocking < 0 or t < step:
                step, blocking = t, p
    if blocking < 0:
        return -1, 0.0
    for p in range(count):
        lam[p] -= step * joining * mu[p]
    joined = m_rows[count].copy()
    count = _drop(active, sign, lam, target, m_rows, chol, count, blocking)
    m_rows[count] = joined
    return count, step


@numba.njit(cache=True)
def _refine(active, sign, upper, lower, slack, chol, count, lam, residual, delta):  # pragma: no cover - compiled
    """One step of iterative refinement of the working set's multipliers (in place): the active
    rows' residual ``M_A x - b_A`` (from ``slack``) through the Gram matrix's factor, added to lam
    (``M_A M_A' delta = M_A x - b_A`` puts ``M_A x`` on ``b_A``). With the rate rows the working
    set's Gram matrix reaches condition numbers of 1e13, and its factor, appended and downdated
    over hundreds of iterations, leaves active rows 1e-5 N m off their bounds without it."""
    for p in range(count):
        r = active[p]
        residual[p] = slack[r] - (upper[r] if sign[r] > 0 else lower[r])
    cholesky_substitute(chol[:count, :count], residual[:count], delta[:count])
    for p in range(count):
        lam[p] += delta[p]


@numba.njit(cache=True, inline="always")
def _solver_arrays(n, horizon, count_rows):  # pragma: no cover - compiled
    """The work arrays of :func:`solve_plan_qp` for n joints, N = ``horizon`` steps and
    ``count_rows`` rows: ``d`` (the whitened gradient), the two (N,) work vectors, the working set
    ``active`` (in order of joining), the rows' ``sign`` (+1 / -1 / 0), the working set's whitened
    rows ``m_rows`` (and one joining), its Gram matrix and factor, the multipliers ``lam`` (by
    position), ``target`` (the second half: :func:`_refine`'s residual), ``star``, ``x``, the moves
    and the rows' slack."""
    size = n * horizon
    return (
        np.empty((n, horizon)), np.empty(horizon), np.empty(horizon),
        np.empty(size, dtype=np.int64), np.zeros(count_rows, dtype=np.int64),
        np.empty((size + 1, n, horizon)), np.empty((size + 1, size + 1)), np.empty((size + 1, size + 1)),
        np.zeros(size + 1), np.empty(2 * size + 2), np.empty(size + 1),
        np.empty((n, horizon)), np.empty(size), np.empty(count_rows),
    )  # fmt: skip


@numba.njit(cache=True, inline="always")
def _blocking_multiplier(active, sign, lam, star, count, dual_tol):  # pragma: no cover - compiled
    """``(p, alpha)``: the working set's first multiplier to change sign on the way from ``lam``
    to ``star`` (position p, -1: none) and the step fraction alpha to it (1.0 when none)."""
    blocking = -1
    alpha = 1.0
    for p in range(count):
        s = sign[active[p]]
        if s * star[p] < -dual_tol:
            step = lam[p] / (lam[p] - star[p])
            if blocking < 0 or step < alpha:
                alpha, blocking = step, p
    return blocking, alpha


@numba.njit(cache=True)
def solve_plan_qp(
    factors, gradient, rows, upper, lower, warm, primal_tol, dual_tol, max_iterations
):  # pragma: no cover - compiled
    """``(moves (N n,), lam (m,), flag, iterations)`` of the horizon QP (module docstring).

    ``factors`` (n, N, N) from :func:`joint_factors`; ``gradient`` g (N n,); ``rows`` R (N n, N n),
    the torque rows, block lower triangular in steps; ``upper``, ``lower`` (m,): m = N n, the
    torque rows alone, or m = 2 N n, the torque rows and below them the rate rows ``R_k - R_{k-1}``
    (row block k less block k - 1; block 0 itself), formed here from R (module docstring);
    ``warm`` (m,) int: the working set to start from (+1 at the upper bound, -1 at the lower,
    0 free: e.g. the signs of a last solve's ``lam``). ``lam``: the multipliers of the rows (> 0 at
    an upper bound, < 0 at a lower), as DAQP's ``info["lam"]``; ``flag``: :data:`SOLVED`,
    :data:`ITERATION_LIMIT` or :data:`INFEASIBLE`. The working set holds at most N n rows (the
    rank of the rows); with the rate rows a joining row dependent on it first takes a member's
    place (:func:`_make_room`)."""
    n, horizon = factors.shape[0], factors.shape[1]
    size = n * horizon
    count_rows = upper.shape[0]
    rated = count_rows > size
    d, work_in, work_out, active, sign, m_rows, gram, chol, lam, target, star, x, moves, slack = _solver_arrays(
        n, horizon, count_rows
    )
    _whiten(factors, gradient, d, work_in, work_out)
    bounds, work = (upper, lower, d), (work_in, work_out)
    if rated:
        count = _load_independent(factors, rows, warm, bounds, active, sign, m_rows[:size], gram, chol, target, work)
    else:
        count = _load_working_set(factors, rows, warm, bounds, active, sign, m_rows, gram, target, work)
        _refactor(gram, count, chol)
    iterations = 0
    refined = 0
    flag = ITERATION_LIMIT
    while iterations < max_iterations:
        iterations += 1
        _unconstrained_multipliers(chol, count, target, star)
        blocking, alpha = _blocking_multiplier(active, sign, lam, star, count, dual_tol)
        if blocking >= 0:
            for p in range(count):
                lam[p] += alpha * (star[p] - lam[p])
            count = _drop(active, sign, lam, target, m_rows, chol, count, blocking)
            continue
        for p in range(count):
            lam[p] = star[p]
        worst = _primal_and_most_violated(
            factors, rows, upper, lower, sign, m_rows, lam, d, count, primal_tol, x, moves, slack
        )
        while worst < 0 and rated and refined < REFINEMENTS:  # refine, then check again
            refined += 1
            _refine(active, sign, upper, lower, slack, chol, count, lam, target[size + 1 :], star)
            worst = _primal_and_most_violated(
                factors, rows, upper, lower, sign, m_rows, lam, d, count, primal_tol, x, moves, slack
            )
        if worst < 0:
            flag = SOLVED
            break
        # the most violated row joins: append its row of the Cholesky factor of M_A M_A'
        joining = 1 if slack[worst] > upper[worst] else -1
        _row(factors, rows, worst, m_rows[count], work_in, work_out)
        _gram_row(m_rows, count, gram)
        _append_cholesky(gram, chol, count)
        start = 0.0
        if rated and (count == size or _dependent(gram, chol, count)):
            count, start = _make_room(active, sign, lam, target, m_rows, gram, chol, count, joining, star, dual_tol)
            if count < 0:
                flag = INFEASIBLE
                count = 0
                break
            _gram_row(m_rows, count, gram)
            _append_cholesky(gram, chol, count)
        active[count] = worst
        sign[worst] = joining
        target[count] = _member_target(m_rows[count], upper[worst] if joining > 0 else lower[worst], d)
        lam[count] = joining * start
        count += 1
    multipliers = np.zeros(count_rows)
    for p in range(count):
        multipliers[active[p]] = lam[p]
    return moves, multipliers, flag, iterations


def warm_set(lam: np.ndarray | None, size: int) -> np.ndarray:
    """The working set (size,) int64 of :func:`solve_plan_qp` from a last solve's multipliers
    (their signs), or empty (None)."""
    if lam is None:
        return np.zeros(size, dtype=np.int64)
    return np.sign(np.nan_to_num(np.asarray(lam, dtype=float))).astype(np.int64)
