"""The rows of the reproduction's Tables 1-2 and the paper's own numbers (Liu et al. 2023,
section 7): the paper's rows and hydroarm's (:data:`ROWS`), the replicated ones, the paper's E_p
and gains. :mod:`hydroarm.studies.reproduce` plans and runs them; :mod:`hydroarm.studies.reproduce_numbers`
turns their runs into summary.json's numbers and the tables."""

from __future__ import annotations

from hydroarm.control.registry import PAPER_CONTROLLERS

# The rows of Tables 1-2 and the paper's own numbers

NOISE_VARIANCE = 0.001
"""The measurement noise of Table 2: variance on each measured q and v (rad^2, (rad/s)^2)."""

PAPER_EP = {
    "clean": {
        "SMC": [1.5872, 2.9348, 2.3282, 9.1378, 1.9941, 2.8227],
        "MPC": [0.09138, 0.1068, 0.2648, 0.3525, 0.2296, 0.2039],
        "GP-MPC": [0.0504, 0.0986, 0.1963, 0.1552, 0.1351, 0.1452],
    },
    "noisy": {
        "SMC": [3.2783, 5.391, 2.3581, 5.2402, 4.7431, 5.1747],
        "MPC": [0.1996, 0.2092, 0.4074, 0.5832, 2.3808, 0.3379],
        "GP-MPC": [0.1226, 0.1333, 0.1591, 0.3152, 0.2011, 0.2017],
    },
}
PAPER_GAIN = {"clean": 34.05, "noisy": 52.27}
"""The paper's "average control accuracy" gain of GP-MPC over MPC: the mean of the per-joint gains (%)."""

BEST = "GP-IDMPC+KF"
"""hydroarm's flagship row (the alias ``flagship``): GP-IDMPC behind its (default) Kalman filter."""

EXTRA_ROWS: dict[str, tuple[str, dict]] = {
    BEST: ("GP-IDMPC", {"estimator.kind": "auto"}),
    "SMC+KF": ("SMC", {"estimator.kind": "kalman"}),
    "MPC+KF": ("MPC", {"estimator.kind": "kalman"}),
    "GP-MPC+KF": ("GP-MPC", {"estimator.kind": "kalman"}),
    "IDMPC+KF": ("IDMPC", {"estimator.kind": "auto"}),
    "IDMPC+TDE+KF": ("IDMPC", {"observer.kind": "tde"}),
    "IDMPC+TDE-gated+KF": ("IDMPC", {"observer.kind": "tde", "observer.gate": True}),
    "IDMPC+NDOB+KF": ("IDMPC", {"observer.kind": "ndob"}),
    "IDMPC+NDOB-gated+KF": ("IDMPC", {"observer.kind": "ndob", "observer.gate": True}),
    "PI-IDMPC+KF": ("PI-IDMPC", {"estimator.kind": "auto"}),
}
"""Rows beyond the paper's: row name -> (registered controller, settings). Each row's name is
what its controller reports (``Trajectory.meta["controller"]``). The IDMPC rows are the fair
baselines of a learned disturbance model: no estimate, and the classic observers (TDE, NDOB with
L = 0.1, each with and without the saturation gate, :mod:`hydroarm.control.observers`) in the
same inverse-dynamics MPC behind the same filter."""

ROWS: tuple[str, ...] = (*PAPER_CONTROLLERS, *EXTRA_ROWS)
"""Every row of Tables 1-2, in their order."""


PAPER_DURATION = 10.0
"""s: the paper's task (its Tables 1-2)."""

REPLICATED_ROWS: tuple[str, ...] = ("GP-MPC", "GP-MPC+KF", BEST, "PI-IDMPC+KF")
"""The rows whose closed loop amplifies a last-bit difference into another run (the sliding-window
GP's accept / reject of each hyperparameter step; PI-IDMPC's planner, whose plans and active sets
follow its learned model): measured, the quick reproduction under OpenBLAS's Haswell and
Sandybridge kernels moved the GP rows' clean E_p by up to 39 % while every other row agreed to
2e-10 (docs/data/reproducibility.md), and once PI-IDMPC's rollout was compiled (2026-12-04) its
clean and noisy rows moved beyond 1e-9 between OpenBLAS Haswell and Prescott with numba generic.
Their clean runs are repeated from :data:`REPLICA_OFFSET`-perturbed starts and reported as a mean
and a spread (:func:`replica_summary`)."""

REPLICA_OFFSET = 1e-12
"""rad: the half-width of the uniform draw added to each joint's start position of a replica
(``initial_state.position_spread``, drawn with ``initial_state.seed`` = the replica's number)."""

DEFAULT_REPLICAS = {"full": 8, "quick": 4}
"""K, the runs per replicated row (the unperturbed one included), by mode."""

ABLATION_REPLICAS = 4
"""The most runs per GP cell of the ablations (``reproduce.ablation_runs``): each compares settings
by the first digits of a mean, and its 36 GP cells would make 8 runs each the study's longest part."""

MAX_REPLICAS = 64
"""The most runs per replicated row ``--replicas`` takes."""
