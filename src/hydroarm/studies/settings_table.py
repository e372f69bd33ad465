"""Every setting, generated from the config models: ``hydroarm settings`` and docs/settings.md.

:func:`settings_table` walks a config model (by default :class:`ExperimentConfig`) and
returns one :class:`SettingRow` per dotted key: its default, the kind of value, the allowed
range (from the pydantic constraints: ``ge``/``gt``/``le``/``lt``, ``Literal`` choices,
list lengths) and the field's description (with its unit). Nothing here is written by
hand, so the table cannot drift from what validation accepts.
"""

from __future__ import annotations

import json
import types
import typing
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import annotated_types
import pydantic
from pydantic.fields import FieldInfo

from hydroarm.control.registry import REGISTRY, controller_spec, declared_settings
from hydroarm.sim.experiment import ExperimentConfig

GENERAL_SECTIONS: tuple[str, ...] = (
    "", "water", "water.current", "plant", "sensor", "actuator", "friction", "initial_state",
    "vehicle", "vehicle.control", "vehicle.gp", "vehicle.plant",
)  # fmt: skip
"""The sections every run reads, whatever its controller ("": the top-level keys)."""

SECTION_TITLES: dict[str, str] = {"": "the run"}


@dataclass(frozen=True)
class SettingRow:
    """One setting: its dotted ``key``, ``default`` (as JSON), the ``kind`` of value, what is
    ``allowed`` (range, choices, lengths; "" = any value of its kind), its ``description``
    (with the unit) and its ``section`` (the dotted key of the model it belongs to; "" top level)."""

    key: str
    default: Any
    kind: str
    allowed: str
    description: str
    section: str


def _number(value: Any) -> str:
    if isinstance(value, int) and not isinstance(value, bool):
        return "2^63 - 1" if value == 2**63 - 1 else str(value)
    return f"{value:g}"


def _bounds(metadata: list[Any]) -> str:
    """``0 < x <= 3600`` from annotated-types constraints (``""`` if none)."""
    low = high = ""
    for item in metadata:
        if isinstance(item, annotated_types.Gt):
            low = f"{_number(item.gt)} < "
        elif isinstance(item, annotated_types.Ge):
            low = f"{_number(item.ge)} <= "
        elif isinstance(item, annotated_types.Lt):
            high = f" < {_number(item.lt)}"
        elif isinstance(item, annotated_types.Le):
            high = f" <= {_number(item.le)}"
    return f"{low}x{high}" if low or high else ""


def _lengths(metadata: list[Any]) -> tuple[int | None, int | None]:
    low = high = None
    for item in metadata:
        if isinstance(item, annotated_types.MinLen):
            low = item.min_length
        elif isinstance(item, annotated_types.MaxLen):
            high = item.max_length
    return low, high


def _unwrap(annotation: Any, metadata: list[Any]) -> list[tuple[Any, list[Any]]]:
    """The members of a union, each with its constraints (``Annotated`` unwrapped)."""
    origin = typing.get_origin(annotation)
    if origin is typing.Annotated:
        inner, *extra = typing.get_args(annotation)
        found = list(metadata)
        for item in extra:
            found += item.metadata if isinstance(item, FieldInfo) else [item]
        return _unwrap(inner, found)
    if origin in (typing.Union, types.UnionType):
        return [member for arg in typing.get_args(annotation) for member in _unwrap(arg, metadata)]
    return [(annotation, metadata)]


_NAMES = {bool: "bool", int: "int", float: "float", str: "text"}


def _describe(annotation: Any, metadata: list[Any]) -> tuple[str, str]:
    """(kind, allowed) of a field's annotation and constraints."""
    kinds, allowed = [], []
    nullable = False
    for member, meta in _unwrap(annotation, metadata):
        origin = typing.get_origin(member)
        if member is type(None):
            nullable = True
        elif origin is typing.Literal:
            kinds.append("choice")
            allowed.append("one of " + ", ".join(str(c) for c in typing.get_args(member)))
        elif member is bool:
            kinds.append("bool")
            allowed.append("true or false")
        elif member in _NAMES:
            kinds.append(_NAMES[member])
            allowed.append(_bounds(meta))
        elif origin in (list, tuple):
            args = typing.get_args(member)
            fixed = origin is tuple and Ellipsis not in args
            item_kind, item_allowed = _describe(args[0], [])
            low, high = (len(args), len(args)) if fixed else _lengths(meta)
            if low is not None and low == high:
                count = f"{low}"
            elif low is not None or high is not None:
                count = f"{low or 0} to {high}" if high is not None else f"at least {low}"
            else:
                count = "any number of"
            kinds.append(f"list of {item_kind}")
            allowed.append(f"{count} values" + (f", each {item_allowed}" if item_allowed else ""))
        else:
            kinds.append(getattr(member, "__name__", str(member)))
            allowed.append("")
    if len(kinds) == 2 and kinds[0] in ("float", "int") and kinds[1] == f"list of {kinds[0]}":  # per joint
        count = allowed[1].split(" values")[0]
        lengths = "" if count == "any number of" else f" (a list: {count} values)"
        kinds, allowed = [f"{kinds[0]} or one per joint"], [allowed[0] + lengths]
    kind = " or ".join(dict.fromkeys(kinds))
    text = "; or ".join(a for a in dict.fromkeys(allowed) if a)
    if nullable:
        kind += ", or null"
        text = f"{text}, or null" if text else "or null"
    return kind, text


def _model_of(annotation: Any) -> type[pydantic.BaseModel] | None:
    members = [m for m, _ in _unwrap(annotation, []) if isinstance(m, type) and issubclass(m, pydantic.BaseModel)]
    return members[0] if len(members) == 1 else None


def _json(value: Any) -> Any:
    if isinstance(value, pydantic.BaseModel):
        return value.model_dump(mode="json")
    if isinstance(value, tuple):
        return [_json(v) for v in value]
    if isinstance(value, Path):
        return str(value)
    return value


def settings_table(
    model: type[pydantic.BaseModel] = ExperimentConfig, prefix: str = "", defaults: pydantic.BaseModel | None = None
) -> list[SettingRow]:
    """One row per dotted key of ``model`` and its sections (sections themselves are not rows).
    ``defaults``: the instance whose values are the defaults (a section's default is the one its
    parent gives it, which may differ from the section model's own field defaults: PI-IDMPC's
    ``water_model.remainder`` is a TDE where :class:`ObserverConfig` alone has none); None: the
    field defaults."""
    rows: list[SettingRow] = []
    section = prefix.removesuffix(".")
    for name, field in model.model_fields.items():
        if defaults is not None:
            value = getattr(defaults, name)
        else:
            value = field.get_default(call_default_factory=True) if not field.is_required() else None
        inner = _model_of(field.annotation)
        if inner is not None:
            rows += settings_table(inner, f"{prefix}{name}.", value if isinstance(value, inner) else None)
            continue
        kind, allowed = _describe(field.annotation, list(field.metadata))
        default = _json(value) if defaults is not None or not field.is_required() else "(required)"
        rows.append(SettingRow(prefix + name, default, kind, allowed, field.description or "", section))
    return rows


def section_descriptions(model: type[pydantic.BaseModel] = ExperimentConfig, prefix: str = "") -> dict[str, str]:
    """Section key -> the description of the field that holds it (``"water"`` -> ...)."""
    out = dict(SECTION_TITLES) if not prefix else {}
    for name, field in model.model_fields.items():
        inner = _model_of(field.annotation)
        if inner is not None:
            out[prefix + name] = (field.description or "").removesuffix(" (section)")
            out.update(section_descriptions(inner, f"{prefix}{name}."))
    if not prefix and model is ExperimentConfig:
        for spec in REGISTRY.values():
            for name, declared in spec.settings.items():
                out[name] = f"declared by the registered controller {spec.name}"
                out.update(section_descriptions(declared, f"{name}."))
    return out


def controller_sections(controller: str | None) -> tuple[str, ...] | None:
    """The sections a run of ``controller`` reads: :data:`GENERAL_SECTIONS`, the registry's
    sections of the controller, and ``estimator`` (every controller may run behind one);
    None: every section. Raises ConfigError for an unknown controller."""
    if controller is None:
        return None
    spec = controller_spec(controller)
    return (*GENERAL_SECTIONS, *spec.sections, "estimator")


def experiment_settings(controller: str | None = None) -> list[SettingRow]:
    """The rows of :class:`ExperimentConfig`; only the sections ``controller`` reads if given."""
    rows = settings_table(ExperimentConfig)
    for name, model in declared_settings().items():  # sections registered controllers declare
        rows += settings_table(model, f"{name}.")
    sections = controller_sections(controller)
    if sections is None:
        return rows
    return [row for row in rows if row.section.split(".")[0] in sections]


def _shown(value: Any) -> str:
    """A default as written in a settings file / after ``--set key=`` (JSON; ``null`` for None)."""
    return value if value == "(required)" else json.dumps(value)


def _sections(rows: list[SettingRow]) -> dict[str, list[SettingRow]]:
    grouped: dict[str, list[SettingRow]] = {}
    for row in rows:
        grouped.setdefault(row.section, []).append(row)
    return grouped


def settings_text(
    rows: list[SettingRow], columns: int | None = None, titles: dict[str, str] | None = None, top: str | None = None
) -> str:
    """Plain text, one line per key: ``key = default  [kind; allowed]  description``; with
    ``columns`` (a terminal's width), a key whose line would be wider gets ``key = default
    [kind; allowed]`` on one line and its description wrapped below it, indented. ``titles``:
    each section's line (default: the run's sections); ``top``: the title of the keys outside a
    section (default: the run's top level)."""
    import textwrap

    titles = section_descriptions() if titles is None else titles
    top = "top level: the run" if top is None else top
    width = min(48, max(len(f"{row.key} = {_shown(row.default)}") for row in rows))
    lines = []
    for section, members in _sections(rows).items():
        title = f"[{section}]  {titles.get(section, '')}" if section else top
        lines += textwrap.wrap(title, columns, subsequent_indent="    ") if columns else [title]
        for row in members:
            left = f"{row.key} = {_shown(row.default)}"
            kind = f"{row.kind}; {row.allowed}" if row.allowed else row.kind
            line = f"  {left:<{width}}  [{kind}]  {row.description}"
            if columns is None or len(line) <= columns:
                lines.append(line)
                continue
            lines += textwrap.wrap(f"{left}  [{kind}]", columns, initial_indent="  ", subsequent_indent="      ")
            lines += textwrap.wrap(row.description, columns, initial_indent="      ", subsequent_indent="      ")
        lines.append("")
    return "\n".join(lines)


def other_settings_text(columns: int | None = None) -> str:
    """The settings beside a run's, as :func:`settings_text` prints them: the replay's (``hydroarm
    replay`` / ``calibrate --set``, and a calibrated vehicle file's ``[replay]`` table), so that
    plain ``hydroarm settings`` lists every section that ``--markdown`` does (the plant mismatch,
    ``mismatch.*``, is a section of the run's settings)."""
    from hydroarm.studies.replay import ReplayConfig

    return settings_text(
        settings_table(ReplayConfig),
        columns,
        titles=section_descriptions(ReplayConfig),
        top="replay: hydroarm replay / calibrate --set key=value, or a calibrated vehicle file's [replay] table",
    )


def settings_json(rows: list[SettingRow]) -> str:
    return json.dumps([asdict(row) for row in rows], indent=1)


def _cell(text: str) -> str:
    return text.replace("|", "\\|")


def settings_markdown() -> str:
    """docs/settings.md: every setting of :class:`ExperimentConfig`, by section, and which
    controller reads which section (``hydroarm settings --markdown > docs/settings.md``)."""

    titles = section_descriptions()
    lines = [
        "# Settings",
        "",
        "<!-- Generated by `hydroarm settings --markdown > docs/settings.md`; do not edit by hand",
        "     (tests/test_settings.py checks it is up to date). -->",
        "",
        "Every setting of a run (`hydroarm.sim.experiment.ExperimentConfig`), generated from the",
        "config models. Set them in a TOML/YAML file (`--config FILE`, sections as tables: `[mpc]`),",
        "with `--set key=value` (dotted keys: `--set mpc.r=0.001`), in a sweep file's `[base]` and",
        '`[parameters]`, or in Python with `with_overrides(config, {"mpc.r": 1e-3})`. A value outside',
        "its range, or an unknown key, stops the command before any work starts (exit code 2).",
        "`hydroarm settings --controller gp-mpc` shows only what one controller reads; `--json` gives",
        "this table as data.",
        "",
        "Per-joint settings take one value (every joint) or a list of one value per joint. `null`",
        "(`--set torque_limit=null`; leave the key out in a file) means the documented default.",
        "",
        "| controller | reads the sections |",
        "|---|---|",
    ]
    for name, spec in REGISTRY.items():
        lines.append(f"| {name} (`{name.lower()}`) | {', '.join(f'`{s}`' for s in (*spec.sections, 'estimator'))} |")
    lines += [
        "",
        "Every run on a fixed base also reads the top-level keys and `water`, `plant`, `sensor`, `actuator`, "
        "`friction`, `initial_state` and `mismatch`; a run on a vehicle (`vehicle.name` set) reads `vehicle` and "
        "refuses `plant`, `sensor`, `actuator`, `friction`, `mismatch`, `water.current` and "
        "`water.quadrature_points` (see the precedence table).",
        "",
    ]
    for section, members in _sections(settings_table()).items():
        lines += [f"## `{section}`: {titles.get(section, '')}" if section else "## Top level: the run", ""]
        lines += ["| key | default | allowed | description |", "|---|---|---|---|"]
        for row in members:
            allowed = f"{row.kind}; {row.allowed}" if row.allowed else row.kind
            lines.append(
                f"| `{row.key}` | `{_cell(_shown(row.default))}` | {_cell(allowed)} | {_cell(row.description)} |"
            )
        lines.append("")
    from hydroarm.studies.replay import ReplayConfig

    lines += [
        "",
        "## Replaying logs: `hydroarm replay` and `hydroarm calibrate`",
        "",
        "`hydroarm replay LOGS --set cleaning.smoothing=1e-3` (the physics is the vehicle and arm files';",
        "docs/validation-real.md).",
        "",
        "| key | default | allowed | description |",
        "|---|---|---|---|",
    ]
    for row in settings_table(ReplayConfig):
        allowed = f"{row.kind}; {row.allowed}" if row.allowed else row.kind
        lines.append(f"| `{row.key}` | `{_cell(_shown(row.default))}` | {_cell(allowed)} | {_cell(row.description)} |")
    from hydroarm.studies.settings_resolved import precedence_markdown

    lines += ["", *precedence_markdown(), "", *system_markdown(), "", *schema_markdown()]
    return "\n".join(lines).rstrip("\n") + "\n"


def system_markdown() -> list[str]:
    """docs/settings.md's section on the system a run simulates and the sections controllers declare."""
    from hydroarm.sim.settings_rules import SYSTEM_ONLY

    only = {system: ", ".join(f"`{key}`" for key in keys) for system, keys in SYSTEM_ONLY.items()}
    return [
        "## One system per run, and the sections controllers declare",
        "",
        "A run simulates one system: the arm on a fixed base (`vehicle.name` null, the default) or the arm on a",
        "vehicle (`vehicle.name` set, `hydroarm run --vehicle NAME`). What only one system reads is one table",
        "(`hydroarm.sim.settings_rules.SYSTEM_ONLY`): on a fixed arm only, "
        f"{only['fixed arm']}; on a vehicle only, {only['arm on a vehicle']}.",
        "Any of them away from its default on the other system fails validation with one message naming the",
        "field (exit code 2), before anything is built. Replaying logs (`hydroarm replay`) takes the settings of",
        "its own section above.",
        "",
        "The systems are told apart by that table over one flat layout, not by a union type of one model per",
        "system: what differs runs through sections both systems read (`water.current` and",
        "`water.quadrature_points` are read on a fixed arm only, inside the `water` section both read), so a",
        "union would need a `water` model per system, and a tag that would move keys every settings file,",
        "`--set` and saved run uses. The table gives the union's guarantee on the flat layout: a test sets each",
        "of its keys on the other system and expects the refusal (tests/test_settings_homes.py).",
        "",
        "A controller registered from outside hydroarm may declare its own section",
        '(`register(ControllerSpec(..., settings={"toy": ToyConfig}))`): `--set toy.kp=400` and a `[toy]` table',
        "are then validated against its model, `hydroarm settings` lists it, and run ids leave it out at its",
        "defaults.",
    ]


def schema_markdown() -> list[str]:
    """docs/settings.md's section on the settings' schema version and its migrations."""
    from hydroarm.sim.settings_schema import MIGRATIONS, SCHEMA

    lines = [
        "## Settings written by an older hydroarm: the schema and its migrations",
        "",
        "Settings that hydroarm writes carry the number of the schema they were written at: a saved run's",
        '`meta["schema"]`, `schema = N` at the top of a settings file `hydroarm tune` writes. This hydroarm',
        f"writes schema {SCHEMA}. Reading settings of an older schema applies the migrations after it, in order",
        "(`hydroarm.sim.settings_schema`); a run saved before schema numbers reads as schema 1, a settings file",
        "without `schema` as today's (a key that moved is answered with its new name). Settings of a newer schema",
        "are refused with one message (exit code 2). Run ids and digests leave out what a migration added where",
        "it holds the value the migration gives it, so the runs made before it keep their ids.",
        "",
        "| schema | what changed | appeared (its value where absent) | moved |",
        "|---|---|---|---|",
    ]
    for migration in MIGRATIONS:
        appeared = [f"`{section}` (its defaults)" for section in migration.sections]
        appeared += [f"`{key}` (`{_cell(_shown(value))}`)" for key, value in migration.keys.items()]
        moved = ", ".join(f"`{old}`" for old in migration.moved)
        if migration.moved:  # one section's keys to another's (the keys keep their names)
            moved += " to " + ", ".join(sorted({f"`{new.split('.')[0]}`" for new in migration.moved.values()}))
        lines.append(f"| {migration.schema} | {_cell(migration.what)} | {', '.join(appeared)} | {moved} |")
    return lines
