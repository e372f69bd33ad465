"""The floating system's state layout is one object (issue 33, "rooms by concept"):
``StateLayout`` names every part of ``x = [q, v, thrust]``, the parts tile the state, the
plants and the controller read their parts through it, and nothing in src slices it by hand."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

import hydroarm
from hydroarm.model.vehicle.system import StateLayout, build_uvms
from hydroarm.sim.experiment import ExperimentConfig, build_experiment
from hydroarm.sim.vehicle import VehicleRun

SOURCE = Path(hydroarm.__file__).parent


@pytest.mark.parametrize(("n_arm", "n_thrusters"), [(0, 0), (4, 8), (6, 0)])
def test_the_parts_tile_the_state(n_arm, n_thrusters):
    layout = StateLayout(n_arm, n_thrusters)
    index = np.arange(layout.size)
    assert layout.nq == 7 + n_arm and layout.nv == 6 + n_arm and layout.size == layout.nq + layout.nv + n_thrusters
    assert np.array_equal(np.concatenate([index[layout.q], index[layout.v], index[layout.thrust]]), index)
    assert np.array_equal(np.concatenate([index[layout.base_pose], index[layout.arm_q]]), index[layout.q])
    assert np.array_equal(np.concatenate([index[layout.base_velocity], index[layout.arm_v]]), index[layout.v])
    assert np.array_equal(layout.arm_state(index), np.r_[index[7 : 7 + n_arm], index[13 + n_arm : 13 + 2 * n_arm]])
    with pytest.raises(AttributeError):
        layout.nq = 3  # frozen


def test_the_vehicle_runs_layout_is_its_plants_and_its_controllers():
    """The UVMS's layout has its Pinocchio sizes and thrusters; the plant's joint state and
    record, and the controller's arm state, are the layout's parts of the same state."""
    uvms = build_uvms()
    layout = uvms.layout
    assert (layout.nq, layout.nv, layout.n_thrusters) == (uvms.nq, uvms.nv, uvms.vehicle.n_thrusters)
    config = ExperimentConfig(arm="mount", duration=0.05, vehicle=VehicleRun(name="bluerov2_heavy"))
    experiment = build_experiment(config, "smc")
    plant, controller = experiment.plant, experiment.controller
    assert plant.layout == experiment.uvms.layout == controller.layout
    x = np.random.default_rng(0).standard_normal(plant.state_size)
    assert plant.layout.size == plant.state_size
    assert np.array_equal(plant.joint_state(x), np.r_[x[plant.layout.arm_q], x[plant.layout.arm_v]])
    record = plant.state_record(x)
    assert np.array_equal(record["base_pose"], x[:7]) and np.array_equal(record["thrust"], x[plant.layout.thrust])
    assert controller.arm_controller is controller.controller and not hasattr(controller, "arm")


def test_nothing_in_src_slices_the_floating_state_by_hand():
    """``nq + 6``, ``[7:nq]`` and ``[:7]`` appear only where the layout is defined."""
    pattern = re.compile(r"nq \+ 6|\[7:nq\]|\[:7\]")
    found = {
        f"{path.relative_to(SOURCE).as_posix()}:{number}"
        for path in sorted(SOURCE.rglob("*.py"))
        for number, line in enumerate(path.read_text().splitlines(), 1)
        if pattern.search(line)
    }
    assert {hit.rsplit(":", 1)[0] for hit in found} <= {"model/vehicle/system.py"}, sorted(found)
    assert not any(re.search(r"controller\.arm\b", p.read_text()) for p in SOURCE.rglob("*.py"))
