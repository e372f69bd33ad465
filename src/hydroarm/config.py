"""Validated configuration: loading TOML/YAML files into pydantic models.

Every config model of hydroarm is a frozen pydantic model with
``extra="forbid"``. A wrong value raises :class:`ConfigError`, a ``ValueError``
whose message names the field (as a dotted path such as ``links.2.mass``), the
value given and what is allowed; never a traceback from deep inside NumPy or
Pinocchio.

Types are not coerced across kinds: the models validate in pydantic's strict
mode (see :class:`FrozenModel`), so a boolean where a number is expected
(``horizon = true``), a number where a boolean is expected (``drag = 1``), a
string where a number or a boolean is expected (``r = "0.1"``) or a float where
an integer is expected (``horizon = 10.0``) is an error. An integer is still a
valid float (``rho = 1000``).
"""

from __future__ import annotations

import dataclasses
import difflib
import math
import tomllib
import types
import typing
from collections.abc import Mapping
from pathlib import Path
from typing import Any, TypeVar

import numpy as np
import pydantic

ModelT = TypeVar("ModelT", bound=pydantic.BaseModel)

MAX_SHOWN = 60
"""Characters of a value shown in an error message (longer values are cut with "...")."""

MAX_LINES = 8
"""Problems listed in one error message; the rest are counted."""


class ConfigError(ValueError):
    """A configuration value is missing, unknown or out of its allowed range.

    The message is the whole story (``field = value: what is allowed``). Raised
    from inside a pydantic validator with ``field`` (a dotted path relative to
    the model), ``value`` and ``reason`` set (see :func:`field_error`), it lets
    :func:`format_validation_error` name the full path of the field
    (``links.2.a`` rather than ``links.2``).
    """

    def __init__(self, message: str, *, field: str | None = None, value: Any = None, reason: str | None = None):
        super().__init__(message)
        self.field = field
        self.value = value
        self.reason = reason


def shown(value: Any) -> str:
    """``repr(value)``, cut to :data:`MAX_SHOWN` characters."""
    text = repr(value)
    return text if len(text) <= MAX_SHOWN else text[: MAX_SHOWN - 3] + "..."


def field_error(field: str, value: Any, reason: str, prefix: str = "") -> ConfigError:
    """A :class:`ConfigError` ``"{prefix}{field} = {value}: {reason}"`` that keeps its parts."""
    return ConfigError(f"{prefix}{field} = {shown(value)}: {reason}", field=field, value=value, reason=reason)


# --- the base of every config model -------------------------------------------------


class FrozenModel(pydantic.BaseModel):
    """Base of every config model: immutable, unknown keys rejected, NaN and infinities
    rejected, and validated in pydantic's strict mode (``strict=True``).

    Strict mode refuses what lax mode would convert: a boolean or a string for a
    number, a number or a string for a boolean, a float for an integer (``10.0``),
    a list for a tuple, a string for a ``Path``. It still accepts an int for a float
    and a mapping for a nested model. A field that must take a list for a tuple or a
    string for a ``Path`` (as TOML, YAML and ``--set`` give them) relaxes itself only,
    its items staying strict: ``Annotated[tuple[pydantic.StrictFloat, ...],
    pydantic.Strict(False)]``, as :class:`~hydroarm.control.gp.GPConfig`'s bounds and
    vectors do.

    NumPy scalars: floating and integer ones are valid floats (as is ``numpy.bool_``,
    which strict mode does not tell from a number); NumPy integers and booleans are not
    valid ints or booleans (give ``int(x)``, ``bool(x)``).
    """

    model_config = pydantic.ConfigDict(
        extra="forbid", frozen=True, allow_inf_nan=False, validate_default=True, strict=True
    )


# --- messages -----------------------------------------------------------------------

_NUMBER_TYPES = (int, float)


def _members(annotation: Any) -> list[Any]:
    """The members of a union (``Annotated`` unwrapped), or ``[annotation]``."""
    origin = typing.get_origin(annotation)
    if origin is typing.Annotated:
        return _members(typing.get_args(annotation)[0])
    if origin in (typing.Union, types.UnionType):
        return [m for arg in typing.get_args(annotation) for m in _members(arg)]
    return [annotation]


_TYPE_ERRORS = ("_type", "_parsing", "is_instance_of", "none_required")
_UNKNOWN = object()  # tags an unknown key's line


def _is_type_error(kind: str) -> bool:
    return kind.endswith(_TYPE_ERRORS) or kind in _TYPE_ERRORS


def _clean_location(loc: tuple[Any, ...], data: Any, missing: bool) -> tuple[Any, ...]:
    """The part of a pydantic location that follows ``data``: union member tags
    (``constrained-float``, ``list[...]``) dropped."""
    out = []
    node = data
    for k, part in enumerate(loc):
        last = k == len(loc) - 1
        if isinstance(node, Mapping) and part in node:
            node = node[part]
        elif isinstance(node, (list, tuple)) and isinstance(part, int) and 0 <= part < len(node):
            node = node[part]
        elif isinstance(part, str) and not isinstance(node, (Mapping, list, tuple, str)) and hasattr(node, part):
            node = getattr(node, part)
        elif isinstance(part, int) or (last and missing) or data is None:
            node = None
        else:
            continue  # a union member's tag
        out.append(part)
    return tuple(out)


def _location(loc: tuple[Any, ...]) -> str:
    return ".".join(str(part) for part in loc) or "<root>"


def _fields_of(cls: Any) -> list[str] | None:
    """The field names of a pydantic model or dataclass type, else None."""
    if isinstance(cls, type) and issubclass(cls, pydantic.BaseModel):
        return list(cls.model_fields)
    if isinstance(cls, type) and dataclasses.is_dataclass(cls):
        return [field.name for field in dataclasses.fields(cls)]
    return None


def _inner_class(annotation: Any) -> Any:
    """The first model/dataclass type inside an annotation (through unions, lists, dict values)."""
    for member in _members(annotation):
        if _fields_of(member) is not None:
            return member
        for arg in typing.get_args(member):
            found = _inner_class(arg)
            if found is not None:
                return found
    return None


def _classes_along(model: Any, where: tuple[Any, ...]) -> list[Any]:
    """The model/dataclass type of the mapping at ``where[:k]`` for k = 0..len(where)
    (None where it is not known) of ``model``."""
    cls, in_dict = model, False
    out = [cls]
    for part in where:
        if isinstance(part, int) or in_dict:
            in_dict = False
            out.append(cls)  # a list item or a dict value: ``cls`` is already the item's type
            continue
        if part not in (_fields_of(cls) or []):
            return out + [None] * (len(where) + 1 - len(out))
        hints = typing.get_type_hints(cls) if dataclasses.is_dataclass(cls) else None
        annotation = hints[part] if hints is not None else cls.model_fields[part].annotation
        in_dict = any(typing.get_origin(m) is dict for m in _members(annotation))
        cls = _inner_class(annotation)
        out.append(cls)
    return out


def _known_keys(model: Any, where: tuple[Any, ...]) -> list[str] | None:
    """The keys allowed in the mapping at ``where`` (a cleaned location) of ``model``."""
    return _fields_of(_classes_along(model, where)[-1])


def dotted_keys(model: Any, prefix: str = "") -> list[str]:
    """Every dotted key of a config model: its sections (``water.current``) and their fields
    (``water.current.scale``), in field order."""
    keys = []
    for name in _fields_of(model) or []:
        keys.append(prefix + name)
        annotation = model.model_fields[name].annotation if issubclass(model, pydantic.BaseModel) else None
        members = [m for m in _members(annotation) if _fields_of(m) is not None]
        if len(members) == 1 and issubclass(members[0], pydantic.BaseModel):
            keys += dotted_keys(members[0], f"{prefix}{name}.")
    return keys


def close_keys(key: str, known: list[str], count: int = 3) -> list[str]:
    """The known keys nearest to a mistyped ``key`` (difflib), those with the same last part first."""
    leaf = key.rsplit(".", 1)[-1]
    same_leaf = [k for k in known if k.rsplit(".", 1)[-1] == leaf and k != key]
    ratios = {k: difflib.SequenceMatcher(None, key, k).ratio() for k in known}
    near = sorted((k for k in known if ratios[k] >= 0.6), key=lambda k: -ratios[k])
    best = ratios[near[0]] if near else 0.0
    near = [k for k in near if ratios[k] >= best - 0.1]  # only the nearest few, not every fair match
    return list(dict.fromkeys(same_leaf + near))[:count]


def leaf_keys(known: list[str]) -> list[str]:
    """The keys of ``known`` (dotted) that are not a section of another one."""
    sections = {key.rsplit(".", 1)[0] for key in known if "." in key}
    return [key for key in known if key not in sections]


def unknown_key_message(
    key: str,
    known: list[str],
    hint: str | None,
    prefix: str = "",
    moved: Mapping[str, str] | None = None,
    value: Any = None,
) -> str:
    """``unknown setting 'mpc.rr'; did you mean 'mpc.r'? (hint)`` (``prefix``: the path of the
    mapping ``known`` is relative to, e.g. ``base.`` in a sweep file). ``moved`` (old key -> new,
    relative like ``known``): a key that moved is answered with its new name only
    (``unknown setting 'water_model.planner': it moved to 'pi_idmpc.planner' (hint)``).
    ``value``: what the key was given; anything but a mapping (a table) is only answered with
    settings, not sections (``vehicle_controller = "pid"``: ``vehicle.control.kind``, not
    ``vehicle.control``)."""
    word = "setting" if hint else "key"
    text = f"unknown {word} '{prefix}{key}'"
    if moved is not None and key in moved:
        text += f": it moved to '{prefix}{moved[key]}'"
        return text + (f" ({hint})" if hint else "")
    matches = close_keys(key, known if isinstance(value, Mapping) else leaf_keys(known))
    if matches:
        text += "; did you mean " + " or ".join(f"'{prefix}{m}'" for m in matches) + "?"
    return text + (f" ({hint})" if hint else "")


def _unknown_key_text(model: Any, where: tuple[Any, ...], value: Any = None) -> str:
    """An unknown key's message: the nearest known keys, and where to find them all (a model
    with a ``settings_hint``, e.g. the experiment settings, names its dotted keys and its hint,
    and the new name of a key in its ``moved_settings``; other models list the keys allowed at
    that level)."""
    classes = _classes_along(model, where[:-1]) if model is not None else [None]
    for k, cls in enumerate(classes):
        hint = getattr(cls, "settings_hint", None)
        if isinstance(hint, str) and all(isinstance(part, str) for part in where[k:]):
            prefix = "".join(f"{part}." for part in where[:k])
            moved = getattr(cls, "moved_settings", None)
            return unknown_key_message(_location(where[k:]), dotted_keys(cls), hint, prefix, moved, value)
    known = _fields_of(classes[-1])
    location = _location(where[:-1]) + "." if where[:-1] else ""
    text = unknown_key_message(str(where[-1]), known or [], None, location, value=value)
    return text + (f" (allowed: {', '.join(known)})" if known else "")


def format_validation_error(error: pydantic.ValidationError, source: str, data: Any = None, model: Any = None) -> str:
    """One readable line per problem: ``source: field = value: what is allowed``.

    ``data`` (the validated input) lets union member tags be dropped from the
    locations. Of the alternatives of a union, only the errors of the closest
    match are kept (a wrong type is not reported next to a range error of the
    same value). ``model`` (the validated type) lets an unknown key's message
    list the keys allowed there.
    """
    items = []
    for item in error.errors():
        missing = item["type"] == "missing"
        where = _clean_location(tuple(item["loc"]), data, missing)
        cause = (item.get("ctx") or {}).get("error")
        message = item["msg"].removeprefix("Value error, ").removeprefix("Assertion failed, ")
        value = item.get("input")
        if isinstance(cause, ConfigError) and cause.field is not None:
            where = where + tuple(cause.field.split("."))
            value, message = cause.value, cause.reason
        if item["type"] == "model_type" and model is not None and not isinstance(value, Mapping):
            fields = _fields_of(_classes_along(model, where)[-1]) or []
            if fields:  # a section given a value: name its settings
                listed = ", ".join(fields[:4]) + (", ..." if len(fields) > 4 else "")
                message = f"a section, not a setting: set its settings ({listed})"
        items.append((where, item["type"], value, message))
    # Drop the wrong-type errors of union alternatives when another alternative got further:
    # to a range error of the same value, or into its items (``r = [true]`` for
    # ``float | list[float]`` is reported at ``r.0``, not also as "not a number" at ``r``).
    specific = {where for where, kind, _, _ in items if not _is_type_error(kind)}
    deeper = {where[:k] for where, _, _, _ in items for k in range(len(where))}

    def superseded(where: tuple, kind: str) -> bool:
        return _is_type_error(kind) and (where in deeper or any(other[: len(where)] == where for other in specific))

    kept = [entry for entry in items if not superseded(entry[0], entry[1])] or items
    # Merge the alternatives reported for one location; collapse one problem repeated over list items.
    lines: dict[tuple, list] = {}
    for where, kind, value, message in kept:
        if kind in ("extra_forbidden", "unexpected_keyword_argument"):
            lines.setdefault((where, _UNKNOWN), [where, value, [_unknown_key_text(model, where, value)], 0])
            continue
        group = (where[:-1], message) if where and isinstance(where[-1], int) else (where, None)
        if group in lines and group[1] is not None:
            lines[group][3] += 1
            continue
        entry = lines.setdefault(group, [where, value, [], 0])
        if message not in entry[2]:
            entry[2].append(message)
    out = []
    for (_, tag), (where, value, messages, repeats) in lines.items():
        if tag is _UNKNOWN:
            out.append(f"{source}: {messages[0]}")
            continue
        text = "; or ".join(messages)
        if repeats:
            text += f" (and {repeats} more items of {_location(where[:-1])})"
        if not where:
            out.append(f"{source}: {text}")
        elif isinstance(value, Mapping):
            out.append(f"{source}: {_location(where)}: {text}")
        else:
            out.append(f"{source}: {_location(where)} = {shown(value)}: {text}")
    if len(out) > MAX_LINES:
        out = out[:MAX_LINES] + [f"{source}: ... and {len(out) - MAX_LINES} more problems"]
    return "\n".join(out)


def validate(model: type[ModelT], data: Any, source: str) -> ModelT:
    """Validate ``data`` into ``model``; raise :class:`ConfigError` naming every bad field."""
    try:
        return model.model_validate(data)
    except pydantic.ValidationError as error:
        raise ConfigError(format_validation_error(error, source, data, model)) from None


def not_a_file(path: str | Path) -> str:
    """Why ``path`` cannot be read as a file, in a few words: a folder, or no such file."""
    return "a folder, not a file" if Path(path).is_dir() else "no such file"


def read_mapping(path: str | Path) -> dict[str, Any]:
    """Read a TOML (``.toml``) or YAML (``.yaml``/``.yml``) file into a dict.

    Raises :class:`ConfigError` for a missing file, an unknown suffix, a syntax error
    (the parser's message, with line and column) or a top level that is not a mapping.
    """
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"{path}: {not_a_file(path)}")
    suffix = path.suffix.lower()
    if suffix == ".toml":
        try:
            with path.open("rb") as handle:
                data = tomllib.load(handle)
        except (tomllib.TOMLDecodeError, UnicodeDecodeError) as error:
            raise ConfigError(f"{path}: cannot parse: {error}") from None
    elif suffix in (".yaml", ".yml"):
        try:
            import yaml  # optional: only needed for YAML files
        except ImportError:
            raise ConfigError(f"{path}: YAML files need PyYAML (pip install pyyaml)") from None
        try:
            with path.open(encoding="utf-8") as handle:
                data = yaml.safe_load(handle)
        except (yaml.YAMLError, UnicodeDecodeError) as error:
            raise ConfigError(f"{path}: cannot parse: {error}") from None
    else:
        raise ConfigError(f"{path}: unknown config format '{suffix}' (use .toml, .yaml or .yml)")
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: the top level must be a mapping, not {type(data).__name__}")
    return data


def load_model(model: type[ModelT], path: str | Path) -> ModelT:
    """Read and validate a config file into ``model``."""
    return validate(model, read_mapping(path), str(path))


def per_joint(value: float | list[float], n: int, field: str) -> np.ndarray:
    """Broadcast a scalar, or check a per-joint list has n values; shape (n,).

    Raises :class:`ConfigError` naming ``field`` and the value when the length is wrong.
    """
    values = np.asarray(value, dtype=float)
    if values.ndim == 0:
        return np.full(n, float(values))
    if values.shape != (n,):
        raise ConfigError(
            f"{field} = {shown(value)}: {values.size} values for {n} joints: give one value or a list of {n}"
        )
    return values.copy()


def is_per_joint(annotation: Any) -> bool:
    """True for a per-joint field: one number or a list of numbers (``float | list[float]``)."""
    members = _members(annotation)
    scalar = any(m in _NUMBER_TYPES for m in members)
    listed = any(
        typing.get_origin(m) is list and all(item in _NUMBER_TYPES for item in _members(typing.get_args(m)[0]))
        for m in members
    )
    return scalar and listed


def check_joint_counts(config: pydantic.BaseModel, n: int, prefix: str = "") -> None:
    """Check every per-joint list (:func:`is_per_joint`) in ``config`` and its sub-models
    has ``n`` values; raise :class:`ConfigError` naming the first that has not."""
    for name, field in type(config).model_fields.items():
        value = getattr(config, name)
        path = f"{prefix}{name}"
        if isinstance(value, pydantic.BaseModel):
            check_joint_counts(value, n, path + ".")
        elif isinstance(value, list) and is_per_joint(field.annotation):
            per_joint(value, n, path)


def require_finite(name: str, value: float) -> float:
    """Return ``value`` or raise ConfigError if it is NaN or infinite."""
    if not math.isfinite(value):
        raise ConfigError(f"{name} = {value!r}: must be a finite number")
    return value
