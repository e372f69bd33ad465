"""The hydroarm benchmark suite (development tooling; not part of the wheel).

Run it with ``hydroarm bench --out DIR [--quick]`` from a source checkout, or
``PYTHONPATH=bench python -m hydroarm_bench --out DIR [--quick]``. It writes
``DIR/bench.json`` and ``DIR/bench.md`` (bench/README.md explains every measurement):

1. ``breakdown`` (:mod:`~hydroarm_bench.control_steps`): one control step per phase on
   the paper scenario, for GP-MPC, MPC and SMC.
2. ``peers``: the MPC's QP in do-mpc and cvxpy (:mod:`~hydroarm_bench.mpc_peers`), the GP
   step against scikit-learn and GPyTorch (:mod:`~hydroarm_bench.gp_peers`), the plant
   against the dry rigid body (:mod:`~hydroarm_bench.plant`).
3. ``scaling`` (:mod:`~hydroarm_bench.scaling`): GP window, MPC horizon, quadrature points.
4. ``throughput`` (:mod:`~hydroarm_bench.control_steps`): wall time of the paper scenario.
5. ``profile`` (:mod:`~hydroarm_bench.profiling`): cProfile of the GP-MPC closed loop.

Every plant, controller and reference comes from
:func:`hydroarm.sim.experiment.build_experiment` (:mod:`~hydroarm_bench.loop`).
The document is assembled and validated in :mod:`~hydroarm_bench.report` and rendered
in :mod:`~hydroarm_bench.markdown`.
"""

from __future__ import annotations

import importlib

__all__ = ["growth_exponent", "run_benchmarks", "stats_ms", "validate_report"]

_HOMES = {
    "growth_exponent": "hydroarm_bench.stats",
    "run_benchmarks": "hydroarm_bench.suite",
    "stats_ms": "hydroarm_bench.stats",
    "validate_report": "hydroarm_bench.report",
}


def __getattr__(name: str):
    # lazy: ``python -m hydroarm_bench`` limits BLAS threads (environment) before NumPy loads
    if name in _HOMES:
        return getattr(importlib.import_module(_HOMES[name]), name)
    raise AttributeError(f"module 'hydroarm_bench' has no attribute {name!r}")
