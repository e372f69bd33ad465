"""The settings' schema version and its migrations: how settings written by an older hydroarm
are read by this one.

Settings change: sections and keys appear, keys move. A record of settings (a run's
``meta["settings"]`` and ``meta["schema"]``, a settings file with ``schema = k``) carries the
number of the schema it was written at; reading it applies the migrations ``k -> k+1 -> ... ->``
:data:`SCHEMA` in order (:func:`migrate`). Each :class:`Migration` says what appeared, with the
value a record without it holds (for every key so far today's default, which is what the run
ids made before it assumed), and what moved where. Settings written with a schema newer than
this hydroarm's get one message saying so.

The same migrations make the compact form of
:meth:`~hydroarm.sim.experiment.ExperimentConfig.canonical` (digests, run ids): a section or key that
a migration added is left out where it holds the value the migration gives it
(:func:`compact`), so the runs made before it keep their ids. In that form a key's absence
always means its migration's value, which never changes (a default that changes is a new
migration), so the compact form alone names a run: the schema number is written beside it, not
hashed into run ids.

Records without a number (every run folder made before schema numbers) read as schema 1: a
migration only fills what is absent and moves keys of its old name, so applying all of them to
a compact form of any age gives its settings. A settings file without ``schema`` is read as
today's (:data:`SCHEMA`): a key that moved is then answered with one message naming its new home.
"""

from __future__ import annotations

import copy
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from hydroarm.config import ConfigError
from hydroarm.control.pi_idmpc import PIIDMPCConfig

__all__ = ["MIGRATIONS", "SCHEMA", "Migration", "compact", "migrate", "migrated", "moved_settings", "schema_of"]


@dataclass(frozen=True)
class Migration:
    """The step from schema ``schema - 1`` to ``schema``: ``what`` changed, in a few words.

    ``sections``: sections that appeared; a record without one holds it at its defaults.
    ``keys``: dotted keys that appeared in an existing section -> the value a record without
    the key has (the behaviour before it existed). ``moved``: old dotted key -> new dotted key.
    """

    schema: int
    what: str
    sections: tuple[str, ...] = ()
    keys: Mapping[str, Any] = field(default_factory=dict)
    moved: Mapping[str, str] = field(default_factory=dict)

    def apply(self, data: dict[str, Any]) -> dict[str, Any]:
        """``data`` (nested settings of schema ``schema - 1``) as schema ``schema``: the moved keys
        at their new home (a key given at both homes is refused), the new keys filled where absent.
        A new section needs nothing: absent, it validates to its defaults."""
        out = copy.deepcopy(data)
        for old, new in self.moved.items():
            found, value = _pop(out, old)
            if found:
                if _get(out, new)[0]:
                    raise ConfigError(f"{old} (schema {self.schema - 1}) moved to {new}, which is given too: give one")
                _put(out, new, value)
        for key, value in self.keys.items():
            if not _get(out, key)[0]:
                _put(out, key, copy.deepcopy(value))
        return out


_PLANNER_KEYS = tuple(PIIDMPCConfig.model_fields)

MIGRATIONS: tuple[Migration, ...] = (
    Migration(2, "disturbance observers (TDE, NDOB) under SMC, MPC and IDMPC", sections=("observer",)),
    Migration(3, "PI-IDMPC's physics-informed water model", sections=("water_model",)),
    Migration(
        4,
        "the real loop: encoders, drives, joint friction, and the state estimator told of them",
        sections=("sensor", "actuator", "friction"),
        keys={"estimator.measures": "plant", "estimator.delay": "plant", "estimator.repeated": "skip"},
    ),
    Migration(5, "tasks from settings or a file", sections=("task",)),
    Migration(6, "the arm on a vehicle", sections=("vehicle",)),
    Migration(
        7,
        "the water's energy-consistent added mass model and axial drag",
        keys={"water.added_mass_model": "morison", "water.axial_drag": True},
    ),
    Migration(
        8,
        "PI-IDMPC's planner settings move from water_model to their own section, pi_idmpc",
        sections=("pi_idmpc",),
        moved={f"water_model.{key}": f"pi_idmpc.{key}" for key in _PLANNER_KEYS},
    ),
    Migration(9, "the ID-MPCs' delay margin", keys={"idmpc.delay_margin": 0}),
    Migration(10, "the compiled plant", keys={"plant.compiled": False, "plant.drag_points": None}),
    Migration(
        11,
        "the ID-MPCs told the loop delay, and their inertia margin",
        keys={"idmpc.loop_delay": "plant", "idmpc.inertia_margin": 1.5},
    ),
    Migration(12, "the plant mismatch (mismatch.*) inside the settings", sections=("mismatch",)),
    Migration(
        13,
        "PI-IDMPC's planner beside the loop: a plan latency and its worker",
        keys={"pi_idmpc.plan_latency": 0, "pi_idmpc.plan_worker": "inline"},
    ),
    Migration(
        14,
        "the arm's friction model fed forward under the ID-MPCs",
        keys={"idmpc.friction_feedforward": "arm"},
    ),
    Migration(
        15,
        "PI-IDMPC's plan cost bounded: an active-set iteration budget per plan and the prediction's RK4 steps",
        keys={"pi_idmpc.planner_budget": 0, "pi_idmpc.plan_prediction_steps": 10},
    ),
    Migration(
        16,
        "GP-IDMPC's GP target chosen: its RK4 residual or the torque map's Euler one",
        keys={"idmpc.gp_residual": "rk4"},
    ),
    Migration(
        17,
        "GP-IDMPC behind a told loop delay: what its GP's estimate feeds forward",
        keys={"idmpc.gp_feedforward_delayed": "none"},
    ),
)
"""Every migration, in order: ``MIGRATIONS[k - 2]`` leads from schema k - 1 to k. The numbers
before 11 were given after the fact (no record carried one), in the order the features came."""

SCHEMA: int = MIGRATIONS[-1].schema
"""The schema this hydroarm writes (``meta["schema"]`` of a run, ``schema =`` of a settings file)."""


def schema_of(value: Any, source: str, missing: int) -> int:
    """The schema number ``value`` of a record (``missing`` where None), checked: an integer in
    [1, :data:`SCHEMA`]; a newer one gets one message saying what to do."""
    if value is None:
        return missing
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        raise ConfigError(f"{source}: schema = {value!r}: must be a whole number >= 1 (the settings' schema version)")
    if value > SCHEMA:
        raise ConfigError(
            f"{source}: schema = {value}: written by a newer hydroarm (settings schema {value}); this hydroarm "
            f"reads schemas 1 to {SCHEMA}: upgrade hydroarm to read it"
        )
    return value


def migrate(data: Mapping[str, Any], schema: int) -> dict[str, Any]:
    """Nested settings ``data`` written at ``schema`` (checked by :func:`schema_of`), as today's
    (:data:`SCHEMA`): every migration after ``schema`` applied in order."""
    out = dict(data)
    for migration in MIGRATIONS:
        if migration.schema > schema:
            out = migration.apply(out)
    return out


def migrated(data: Mapping[str, Any], source: str, missing: int = SCHEMA) -> dict[str, Any]:
    """Nested settings ``data`` with an optional top-level ``schema`` (``missing`` where absent;
    checked by :func:`schema_of`), migrated to today's and without the ``schema`` key; a
    conflict raises :class:`ConfigError` naming ``source``."""
    data = dict(data)
    schema = schema_of(data.pop("schema", None), source, missing)
    try:
        return migrate(data, schema)
    except ConfigError as error:
        raise ConfigError(f"{source}: {error}") from None


def compact(data: dict[str, Any], defaults: Mapping[str, Any]) -> dict[str, Any]:
    """``data`` (the settings as JSON data, today's schema) without what the migrations added
    where it holds the migration's value: a section equal to ``defaults[section]`` (its defaults
    as JSON data), a key equal to its migration's value (``data`` is changed and returned)."""
    for migration in MIGRATIONS:
        for section in migration.sections:
            if section in data and data[section] == defaults[section]:
                data.pop(section)
        for key, value in migration.keys.items():
            found, held = _get(data, key)
            if found and held == value:
                _pop(data, key)
    return data


def moved_settings() -> dict[str, str]:
    """Every key that moved, old dotted key -> its home today (followed through later moves)."""
    moved: dict[str, str] = {}
    for migration in MIGRATIONS:
        for old, new in migration.moved.items():
            moved = {k: (new if v == old else v) for k, v in moved.items()}
            moved[old] = new
    return moved


def _get(data: Mapping[str, Any], key: str) -> tuple[bool, Any]:
    node: Any = data
    for part in key.split("."):
        if not isinstance(node, Mapping) or part not in node:
            return False, None
        node = node[part]
    return True, node


def _pop(data: dict[str, Any], key: str) -> tuple[bool, Any]:
    *path, last = key.split(".")
    node: Any = data
    for part in path:
        if not isinstance(node, Mapping) or part not in node:
            return False, None
        node = node[part]
    if not isinstance(node, dict) or last not in node:
        return False, None
    return True, node.pop(last)


def _put(data: dict[str, Any], key: str, value: Any) -> None:
    *path, last = key.split(".")
    node = data
    for part in path:
        child = node.get(part)
        if not isinstance(child, dict):
            if child is not None:
                return  # not a mapping: left for validation to name
            child = node[part] = {}
        node = child
    node[last] = value
