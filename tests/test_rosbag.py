"""ROS 2 bags in and out (issue 22): a bag written from a log reads back equal, and replay reads a
bag as it reads the CSV."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from hydroarm.cli import app
from hydroarm.sim.logs import load_csv_trial
from hydroarm.sim.rosbag import read_bag, write_bag

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT / "tests" / "data" / "hinsdale-2023"
CALIBRATED = ROOT / "examples" / "hinsdale" / "bluerov2_hinsdale_calibrated.toml"
RUNNER = CliRunner()


def test_bag_reads_back_equal(tmp_path):
    log = load_csv_trial(DATA / "traj_alt_011-1_joint_states.csv")
    back = read_bag(write_bag(tmp_path / "trial", log))
    assert back.joint_names == log.joint_names
    np.testing.assert_array_equal(back.joint_position, log.joint_position)
    np.testing.assert_array_equal(back.imu_quaternion, log.imu_quaternion)
    np.testing.assert_array_equal(back.imu_angular_velocity, log.imu_angular_velocity)
    np.testing.assert_array_equal(back.mocap_quaternion, log.mocap_quaternion)
    for a, b in ((back.joint_time, log.joint_time), (back.imu_time, log.imu_time), (back.mocap_time, log.mocap_time)):
        np.testing.assert_allclose(a, b, rtol=0.0, atol=5e-10)  # header stamps hold whole nanoseconds


def test_replay_reads_the_bag_as_the_csv(tmp_path):
    log = load_csv_trial(DATA / "traj_alt_011-1_joint_states.csv")
    bag = write_bag(tmp_path / "traj_alt_011-1", log)
    summaries = []
    for source, out in ((DATA / "traj_alt_011-1_joint_states.csv", tmp_path / "csv"), (bag, tmp_path / "bag")):
        args = ["replay", str(source), "--vehicle", str(CALIBRATED), "--out", str(out), "--workers", "0"]
        result = RUNNER.invoke(app, [*args, "--no-figures"])
        assert result.exit_code == 0, result.output
        summaries.append(json.loads((out / "summary.json").read_text())["trials"]["traj_alt_011-1"])
    for key, value in summaries[0].items():
        assert summaries[1][key] == (value if value is None else pytest.approx(value, abs=1e-6)), key


def test_run_bag_holds_the_simulated_attitude(tmp_path):
    out = tmp_path / "out"
    args = ["replay", str(DATA / "traj_alt_002-1_joint_states.csv"), "--vehicle", str(CALIBRATED), "--out", str(out)]
    result = RUNNER.invoke(app, [*args, "--workers", "0", "--no-figures", "--bag"])
    assert result.exit_code == 0, result.output
    from rosbags.highlevel import AnyReader

    with AnyReader([out / "traj_alt_002-1" / "replay"]) as reader:
        topics = {c.topic: c.msgcount for c in reader.connections}
    rows = (out / "traj_alt_002-1" / "attitude.csv").read_text().strip().splitlines()
    assert topics["/hydroarm/vehicle_pose"] == len(rows) - 1
    assert {"/joint_states", "/imu", "/mocap/pose"} <= set(topics)


def test_bag_without_imu_is_refused(tmp_path):
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)
    path = tmp_path / "joints_only"
    with Writer(path, version=8, storage_plugin=StoragePlugin.MCAP) as writer:
        writer.add_connection("/joint_states", "sensor_msgs/msg/JointState", typestore=store)
    result = RUNNER.invoke(app, ["replay", str(path), "--vehicle", str(CALIBRATED), "--out", str(tmp_path / "o")])
    assert result.exit_code == 2, result.output
    assert "no sensor_msgs/msg/Imu topic" in result.output.replace("\n", " ")
