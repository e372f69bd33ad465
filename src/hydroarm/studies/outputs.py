"""What the commands write into an output folder: safe file names, strict JSON, and the
folder's manifest, which says which settings made it.

* :func:`slug`: the one way a label becomes a file name or a run id (lowercase,
  ``[a-z0-9._-]``, readable): ``ablation/control period T (s)=0.02`` ->
  ``ablation-control-period-t-s-0.02``, ``GP-IDMPC+KF`` -> ``gp-idmpc-kf``.
* :func:`strict` / :func:`dumps`: JSON without NaN or infinities (``null`` in their
  place), as every JSON file and ``--json`` output of hydroarm is written.
* :data:`MANIFEST` (``hydroarm-run.json``): written first into every output folder of
  ``run``, ``reproduce`` and ``sweep``; it records the command (``kind``), a digest of
  the settings that determine the results, and the runs they are made of.
  :func:`claim_output` checks a folder before a command writes into it: a folder made
  by the same command with the same settings is resumed (``reproduce`` and ``sweep``
  reuse its finished runs); one that only lacks runs of this command (more seeds, the
  ablation added, a sweep extended) is extended; any other folder holding results is
  refused (:class:`OutputConflict`) unless ``overwrite``, which first removes its stale
  files (the results of the other settings) and keeps nothing that the new command would
  not write again.
"""

from __future__ import annotations

import fnmatch
import hashlib
import json
import math
import re
import shutil
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from hydroarm.config import ConfigError
from hydroarm.sim.files import atomic_write

MANIFEST = "hydroarm-run.json"
"""The manifest of an output folder (see the module docstring)."""

FORMAT = 1

RUNS = "runs"
"""The folder of finished runs inside a ``reproduce`` or ``sweep`` output folder."""

OUTPUTS: dict[str, tuple[str, ...]] = {
    "run": ("trajectory.npz", "metrics.json", "position.png", "velocity.png", "torque.png", "disturbance.png"),
    "reproduce": (
        "metrics.json", "summary.json", "report.md", "table1.*", "table2.*", "ablation.*", "ablation_idmpc.*",
        "fig[01][0-9]_*.png", "gpmpc_arm.gif",
    ),
    "sweep": (
        "sweep.json", "results.csv", "summary.md", "summary.json", "failed.json", "ep_boxplot.png",
        "ep_distribution.png", "ep_by_*.png", "robustness.png", "robustness_by_parameter.png",
    ),
}  # fmt: skip
"""The files each command writes at the top of its folder (shell patterns); ``runs/`` besides."""

_UNSAFE = re.compile(r"[^a-z0-9._-]+")


def slug(text: str) -> str:
    """``text`` as a safe, readable file name: lowercase, every run of characters outside
    ``[a-z0-9._-]`` replaced by one ``-``, no leading or trailing ``-``."""
    out = _UNSAFE.sub("-", str(text).lower()).strip("-")
    return out or "-"


def strict(value: Any) -> Any:
    """``value`` with NaN and infinities replaced by None and NumPy values made plain,
    recursively (mappings, lists, tuples): ready for strict JSON."""
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        return float(value) if math.isfinite(value) else None
    if isinstance(value, np.ndarray):
        return strict(value.tolist())
    if isinstance(value, Mapping):
        return {key: strict(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [strict(item) for item in value]
    return value


def dumps(value: Any, indent: int | None = None, **options: Any) -> str:
    """Strict JSON of ``value`` (:func:`strict`: NaN and infinities as ``null``)."""
    return json.dumps(strict(value), indent=indent, allow_nan=False, **options)


class OutputConflict(ConfigError):
    """The output folder holds results of other settings (exit code 2, like a bad setting)."""


def digest(settings: Any) -> str:
    """A short hash of JSON-able ``settings``."""
    return hashlib.sha256(dumps(settings, sort_keys=True).encode()).hexdigest()[:16]


def read_manifest(out: Path) -> dict | None:
    """The folder's manifest, or None if it has none (or an unreadable one)."""
    try:
        manifest = json.loads((Path(out) / MANIFEST).read_text())
    except (OSError, ValueError):
        return None
    return manifest if isinstance(manifest, dict) and manifest.get("format") == FORMAT else None


def _is_output(name: str) -> bool:
    return any(fnmatch.fnmatchcase(name, pattern) for patterns in OUTPUTS.values() for pattern in patterns)


def results_in(out: Path) -> list[str]:
    """The names of hydroarm's results in ``out`` (not other files the folder may hold)."""
    out = Path(out)
    if not out.is_dir():
        return []
    names = [p.name for p in out.iterdir() if p.is_file() and _is_output(p.name)]
    runs = out / RUNS
    if runs.is_dir() and any(runs.iterdir()):
        names.append(f"{RUNS}/")
    return sorted(names, key=lambda name: (not name.endswith((".json", ".md", ".csv", "/")), name))


def _differences(old: Any, new: Any, prefix: str = "") -> list[str]:
    """Dotted keys whose values differ between two JSON settings."""
    if isinstance(old, dict) and isinstance(new, dict):
        keys = list(dict.fromkeys([*old, *new]))
        return [d for key in keys for d in _differences(old.get(key), new.get(key), f"{prefix}{key}.")]
    return [] if old == new else [prefix.removesuffix(".")]


def _what(manifest: dict) -> str:
    return manifest.get("description") or f"hydroarm {manifest.get('kind', '?')}"


def _shown(settings: Any, key: str) -> str:
    value: Any = settings
    for part in key.split("."):
        value = value.get(part) if isinstance(value, dict) else None
    return json.dumps(value)


def claim_output(
    out: Path,
    kind: str,
    settings: dict,
    runs: Mapping[str, str] | None = None,
    description: str = "",
    overwrite: bool = False,
    dry_run: bool = False,
) -> None:
    """Check that command ``kind`` with ``settings`` (JSON) may write into ``out``, clear what
    is stale and write the manifest (``dry_run``: only check, change nothing).

    ``runs``: the runs the command keeps in ``out/runs`` (``reproduce``, ``sweep``), run id
    (the file's stem) -> a digest of its settings (``""`` when the id is one already): a
    folder whose recorded runs are all among them is extended (more seeds, the ablation
    added, a sweep extended), not refused. ``description``: the command in a few words,
    for messages. A folder of other settings raises :class:`OutputConflict` naming the
    folder and what is in it, unless ``overwrite``: then its stale files are removed first
    (every result file of any command, and the run files not among ``runs``).
    """
    out = Path(out)
    runs = dict(runs or {})
    manifest = read_manifest(out)
    found = results_in(out)
    new = {"format": FORMAT, "kind": kind, "digest": digest(settings), "description": description}
    same_kind = manifest is not None and manifest.get("kind") == kind
    same = same_kind and manifest.get("digest") == new["digest"]
    old_runs = manifest.get("runs") if same_kind and isinstance(manifest.get("runs"), dict) else None
    extends = kind != "run" and old_runs is not None and all(runs.get(k) == v for k, v in old_runs.items())
    if found and not (same or extends or overwrite):
        raise OutputConflict(f"--out '{out}' holds {_conflict(manifest, found, kind, settings)}; "
                             "add --overwrite to replace them, or choose another folder")  # fmt: skip
    if dry_run:
        return
    if found and not same:
        _remove_stale(out, runs)
    out.mkdir(parents=True, exist_ok=True)
    atomic_write(out / MANIFEST, dumps({**new, "settings": settings, "runs": runs}, indent=1))


def _conflict(manifest: dict | None, found: list[str], kind: str, settings: dict) -> str:
    """What the folder holds, in a few words: which command made it, and with which settings
    where they differ from this command's."""
    if manifest is None:
        return f"results without a {MANIFEST} (from an older hydroarm, or not made by it): {', '.join(found[:4])}"
    old = manifest.get("settings")
    text = f"the results of {_what(manifest)}"
    if manifest.get("kind") != kind:
        return text
    changed = _differences(old, settings)[:3]
    if changed:
        text += " made with " + ", ".join(f"{k} = {_shown(old, k)}" for k in changed)
        text += " (this command: " + ", ".join(f"{k} = {_shown(settings, k)}" for k in changed) + ")"
    return text


def _remove_stale(out: Path, keep_runs: Mapping[str, str]) -> None:
    """Remove every result file of any command from ``out``, its manifest, and the run files
    whose id (stem) is not in ``keep_runs`` (files not made by hydroarm are left alone)."""
    for path in out.iterdir():
        if path.is_file() and (_is_output(path.name) or path.name == MANIFEST):
            path.unlink()
    runs = out / RUNS
    if runs.is_dir():
        for path in runs.iterdir():
            if (path.stem if path.is_file() else path.name) in keep_runs:
                continue
            if path.is_dir():
                shutil.rmtree(path)
            else:
                path.unlink()
