"""Parameter sweeps: many closed-loop runs over a grid or a random sample of settings.

A sweep file (TOML or YAML, validated into :class:`SweepConfig`) names the
controllers, the seeds, the settings shared by every run (``[base]``, an
:class:`~hydroarm.sim.experiment.ExperimentConfig`) and the settings that vary
(``[parameters]``: dotted keys such as ``mpc.r``, ``water.current.scale``,
``plant.noise_variance``, ``arm``, ``mismatch.mass_scale``)::

    controllers = ["MPC", "GP-MPC"]
    seeds = 2                       # seeds 0 and 1; or a list [0, 4, 7]
    mode = "grid"                   # every combination; "random": `samples` draws

    [base]
    arm = "paper"
    duration = 3.0

    [parameters]
    "water.current.scale" = [0.5, 1.0, 2.0]
    "mismatch.mass_scale" = [1.0, 1.3]
    "mpc.r" = { low = 1e-4, high = 1e-1, num = 4, log = true }

:func:`run_sweep` runs every combination x seed x controller that is not
finished yet, on a local process pool (default) or a Ray cluster, and writes
into its output folder:

* ``sweep.json``: the validated sweep and its plan (one entry per row);
* ``hydroarm-run.json``: the folder's manifest (:mod:`hydroarm.studies.outputs`): a
  folder of another sweep is refused, an extended sweep reuses what it shares;
* ``runs/<id>.json``: one finished run (settings + metrics), written
  atomically; ``<id>`` is the controller and seed, then a hash of everything that
  determines the run (the arm's content, the settings the controller uses, the
  mismatch, controller, seed), so a re-run skips finished runs and recomputes an
  unreadable file;
  ``runs/<id>.npz`` the trajectory when asked for;
* ``results.csv``: one row per run with every setting and metric, rewritten
  atomically after each finished run (an interrupted sweep leaves a readable
  table);
* ``summary.md``, ``summary.json``, ``ep_boxplot.png``, ``ep_by_<key>.png``,
  ``ep_distribution.png``, ``robustness.png``: written by :func:`summarise` at
  the end, with a robustness table (per controller: runs within a tracking
  bound, ``[robustness]`` in the sweep file, runs that stopped, fault counts).

Random starts: ``initial_state.position_spread`` / ``velocity_spread`` in
``[base]`` and ``"initial_state.seed" = {low = 0, high = 1000000, integer =
true}`` in ``[parameters]`` give every sample its own start
(:class:`~hydroarm.sim.experiment.InitialState`).

Model mismatch. The controllers know the arm file (the nominal model); the
true plant is that arm plus the water. ``water.*`` and ``plant.*`` settings
exist only in the plant, so sweeping them is already mismatch;
``mismatch.mass_scale`` (every link's mass and rotational inertia about its
centre of gravity, i.e. the density, times this factor) and
``mismatch.payload_kg`` (a point mass at the flange, or at the last link's
centre of gravity for URDF arms) change the plant's rigid body only
(:func:`perturbed_arm`). The recorded ``disturbance`` of a trajectory is then
relative to the plant's own (perturbed) dry dynamics.

The runs go through the one executor and resume cache of the studies
(:mod:`hydroarm.studies.executor`: in this process, local processes or a Ray
cluster; ``runs/<id>.json`` is the cache).

Modules: :mod:`~hydroarm.studies.sweep.schema` (the sweep file),
:mod:`~hydroarm.studies.sweep.plan` (rows, run ids, the perturbed arm),
:mod:`~hydroarm.studies.sweep.worker` (one run), :mod:`~hydroarm.studies.sweep.results`
(run files, the bound, results.csv), :mod:`~hydroarm.studies.sweep.run` (:func:`run_sweep`),
:mod:`~hydroarm.studies.sweep.summary` and :mod:`~hydroarm.studies.sweep.plots`.
"""

from hydroarm.sim.mismatch import Mismatch, perturbed_arm
from hydroarm.studies.sweep.plan import (
    Plan,
    PlanRow,
    RunTask,
    arm_digest,
    plan_sweep,
    run_id,
    sample_points,
)
from hydroarm.studies.sweep.results import ResultsTable, RunFiles, assess, read_run, steady_max_error
from hydroarm.studies.sweep.run import claim_sweep_folder, run_sweep
from hydroarm.studies.sweep.schema import (
    METRICS,
    Range,
    Robustness,
    SweepConfig,
    check_sweep,
    load_sweep,
    validate_sweep,
)
from hydroarm.studies.sweep.summary import robustness_table, summarise
from hydroarm.studies.sweep.worker import error_envelope, execute_run

__all__ = [
    "METRICS",
    "Mismatch",
    "Plan",
    "PlanRow",
    "Range",
    "ResultsTable",
    "Robustness",
    "RunFiles",
    "RunTask",
    "SweepConfig",
    "arm_digest",
    "assess",
    "check_sweep",
    "claim_sweep_folder",
    "error_envelope",
    "execute_run",
    "load_sweep",
    "perturbed_arm",
    "plan_sweep",
    "read_run",
    "robustness_table",
    "run_id",
    "run_sweep",
    "sample_points",
    "steady_max_error",
    "summarise",
    "validate_sweep",
]
