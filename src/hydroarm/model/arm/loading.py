"""Loading arms: built-in names, DH arm files, URDF + hydrodynamics files -> :class:`Arm`."""

from __future__ import annotations

from importlib import resources
from pathlib import Path

from hydroarm.config import ConfigError, load_model, not_a_file
from hydroarm.model.arm.description import Arm, ArmSpec, build_arm
from hydroarm.model.arm.urdf_import import hydro_file_for, load_hydro_spec, load_urdf_arm

BUILTIN_ARMS = ("paper", "ur5", "alpha5")
BUILTIN_URDF_ARMS = ("alpha5",)
"""Built-in arms given as a URDF plus a hydrodynamics file (``arms/<name>.hydro.toml``)."""

URDF_SUFFIXES = (".urdf", ".hydro.toml", ".hydro.yaml", ".hydro.yml")
"""File names that :func:`load_arm` hands to :mod:`hydroarm.model.arm.urdf_import`."""

DH_SUFFIXES = (".toml", ".yaml", ".yml")
"""File names of DH arm files (:class:`~hydroarm.model.arm.description.ArmSpec`)."""

ARM_FILES = "an arm file is a DH arm file (.toml, .yaml, .yml), a URDF (.urdf) or a hydrodynamics file (.hydro.toml)"


def builtin_arm_path(name: str) -> Path:
    """Path of a built-in arm file: ``arms/<name>.toml`` (DH arms ``paper``, ``ur5``)
    or ``arms/<name>.hydro.toml`` (URDF arms, e.g. ``alpha5``; it names its URDF)."""
    suffix = ".hydro.toml" if name in BUILTIN_URDF_ARMS else ".toml"
    return Path(str(resources.files("hydroarm") / "arms" / f"{name}{suffix}"))


def is_urdf_source(source: str | Path) -> bool:
    """True for a built-in URDF arm name or a ``.urdf`` / ``.hydro.{toml,yaml,yml}`` path."""
    if isinstance(source, str) and source in BUILTIN_URDF_ARMS:
        return True
    return str(source).lower().endswith(URDF_SUFFIXES)


def load_arm_spec(source: str | Path) -> ArmSpec:
    """Read and validate a DH arm file, or a built-in DH arm by name."""
    if is_urdf_source(source):
        raise ConfigError(f"arm {str(source)!r} is a URDF arm: it has no DH arm file; load it with load_arm()")
    if isinstance(source, str) and source in BUILTIN_ARMS:
        return load_model(ArmSpec, builtin_arm_path(source))
    path = Path(source)
    if not str(source) or not path.exists():
        raise ConfigError(
            f"arm {str(source)!r}: neither a built-in arm ({', '.join(BUILTIN_ARMS)}) nor an existing file"
        )
    if path.is_dir():
        raise ConfigError(f"arm {str(source)!r}: {not_a_file(path)}")
    if not path.name.lower().endswith(DH_SUFFIXES):
        raise ConfigError(f"arm {str(source)!r}: unknown arm file type; {ARM_FILES}")
    return load_model(ArmSpec, path)


def load_arm(source: str | Path = "paper") -> Arm:
    """Load an arm: ``"paper"`` (Liu et al. 2023), ``"ur5"``, ``"alpha5"`` (Reach Alpha 5),
    a DH arm file (TOML/YAML), a URDF (``.urdf``, with ``<stem>.hydro.toml`` beside it) or a
    hydrodynamics file (``.hydro.toml``/``.yaml`` naming its URDF): see :mod:`hydroarm.model.arm.urdf_import`."""
    if is_urdf_source(source):
        if isinstance(source, str) and source in BUILTIN_URDF_ARMS:
            return load_urdf_arm(builtin_arm_path(source))
        return load_urdf_arm(source)
    return build_arm(load_arm_spec(source))


def arm_description(source: str | Path) -> str:
    """The one-line ``description`` of an arm: from its DH arm file, or from its hydrodynamics
    file (URDF arms: the built-in's, the file given, or the one beside a ``.urdf``); "" if it
    has none or cannot be read."""
    try:
        if not is_urdf_source(source):
            return load_arm_spec(source).description
        if isinstance(source, str) and source in BUILTIN_URDF_ARMS:
            hydro: Path | None = builtin_arm_path(source)
        elif str(source).lower().endswith(".urdf"):
            hydro = hydro_file_for(source)
        else:
            hydro = Path(source)
        return load_hydro_spec(hydro).description if hydro is not None else ""
    except ConfigError:
        return ""


def tuned_settings_path(arm: str) -> Path:
    """The settings file of gains tuned for built-in ``arm`` (``arms/tuned/<arm>.toml``: the SMC's
    and the MPC's, by ``hydroarm tune`` on the dry arm); :class:`ConfigError` for other arms."""
    path = Path(str(resources.files("hydroarm") / "arms" / "tuned" / f"{arm}.toml"))
    if isinstance(arm, str) and arm not in BUILTIN_ARMS and not Path(arm).exists():
        raise ConfigError(
            f"arm {arm!r}: neither a built-in arm ({', '.join(BUILTIN_ARMS)}) nor an existing file "
            f"(relative paths are relative to the working directory, {Path.cwd()})"
        )
    if not isinstance(arm, str) or not path.is_file():
        raise ConfigError(
            f"--tuned: no tuned settings ship for arm {str(arm)!r} (built-in: {', '.join(BUILTIN_ARMS)}); "
            "make them with `hydroarm tune --arm ARM --controller smc --out FILE` and pass --config FILE"
        )
    return path
