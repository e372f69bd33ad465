"""Trials from paths: CSV trials (:mod:`hydroarm.sim.logs`) and ROS 2 bags (:mod:`hydroarm.sim.rosbag`)
alike, as :class:`~hydroarm.sim.logs.TrialLog`."""

from __future__ import annotations

from pathlib import Path

from hydroarm.sim.logs import LogError, TrialLog, load_csv_trial
from hydroarm.sim.rosbag import read_bag


def find_trials(paths: list[str | Path]) -> list[Path]:
    """The trials named by ``paths``: a ``*_joint_states.csv`` file, a ROS 2 bag (``.mcap`` /
    ``.db3`` file or a bag folder with ``metadata.yaml``), or a folder of ``*_joint_states.csv``."""
    found: list[Path] = []
    for raw in paths:
        path = Path(raw)
        if path.is_dir() and not (path / "metadata.yaml").is_file():
            trials = sorted(path.glob("*_joint_states.csv")) + sorted(path.glob("*.mcap"))
            if not trials:
                raise LogError(f"{path}: no *_joint_states.csv or *.mcap log in this folder")
            found.extend(trials)
        elif path.exists():
            found.append(path)
        else:
            raise LogError(f"{path}: no such file or folder")
    return found


def load_trial(path: str | Path, joint_names: tuple[str, ...] | None = None) -> TrialLog:
    """A trial from a CSV trial or a ROS 2 bag (:func:`find_trials` says which)."""
    path = Path(path)
    if path.suffix in (".mcap", ".db3") or (path.is_dir() and (path / "metadata.yaml").is_file()):
        log = read_bag(path)
        return log.select_joints(joint_names) if joint_names else log
    return load_csv_trial(path, joint_names)
