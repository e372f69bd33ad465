"""The vehicle alone: its file and validation, the allocation matrix, closed forms of roll
restoring and surge decay, the thrust lag (the physics is in docs/vehicle.md)."""

from __future__ import annotations

import dataclasses
import math
import re
import tomllib

import numpy as np
import pytest

from hydroarm.config import ConfigError, validate
from hydroarm.model.vehicle.description import (
    VehicleSpec,
    allocation_matrix,
    builtin_vehicle_path,
    load_vehicle,
)
from hydroarm.model.vehicle.plant import UVMSPlant
from hydroarm.model.vehicle.system import build_uvms
from hydroarm.model.water.morison import Water

RHO, G = 1000.0, 9.81


@pytest.fixture(scope="module")
def bluerov():
    return load_vehicle("bluerov2_heavy")


def _neutral(vehicle, **changes):
    """The vehicle with B = W (V = m / rho), no damping unless given."""
    base = {
        "displaced_volume": vehicle.mass / RHO,
        "linear_damping": np.zeros(6),
        "quadratic_damping": np.zeros(6),
    }
    base.update(changes)
    return dataclasses.replace(vehicle, **base)


# --- the file ----------------------------------------------------------------------------


def test_builtin_vehicle_has_the_benchmark_numbers(bluerov):
    assert bluerov.mass == 13.5 and bluerov.displaced_volume == 0.0134
    assert np.allclose(np.diag(bluerov.inertia), [0.26, 0.23, 0.37])
    assert np.allclose(np.diag(bluerov.added_mass), [6.3567, 7.1206, 18.6863, 0.1858, 0.1348, 0.2215])
    assert np.allclose(bluerov.linear_damping, [13.7, 0.0, 33.0, 0.0, 0.8, 0.0])
    assert np.allclose(bluerov.quadratic_damping, [141.0, 217.0, 190.0, 1.192, 0.47, 1.5])
    assert np.allclose(bluerov.cb, [0.0, 0.0, 0.01]) and bluerov.n_thrusters == 8

    # von Benzon et al.'s Table A1 (NED: x forward, y right, z down): column i = [e_i; r_i x e_i]
    def rot_z(angle):
        c, s = np.cos(angle), np.sin(angle)
        return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])

    half = np.sqrt(0.5)
    columns = []
    # horizontal: the printed beta = 3 pi / 4 of T3 is a typo for 3 pi / 2 (the benchmark's code)
    for alpha, beta in zip((0.0, 5.05, 1.91, np.pi), (0.0, np.pi / 2, 3 * np.pi / 2, np.pi)):
        r, e = rot_z(alpha) @ [0.156, 0.111, 0.085], rot_z(beta) @ [half, -half, 0.0]
        columns.append(np.concatenate([e, np.cross(r, e)]))
    for gamma in (0.0, 4.15, 1.01, np.pi):  # vertical: all four thrust upwards, e = (0, 0, -1)
        r, e = rot_z(gamma) @ [0.120, 0.218, 0.0], np.array([0.0, 0.0, -1.0])
        columns.append(np.concatenate([e, np.cross(r, e)]))
    ned = np.array(columns).T
    flip = np.diag([1.0, -1.0, -1.0, 1.0, -1.0, -1.0])  # NED body axes -> x forward, y left, z up
    # atol 1e-3 m: Table A1 rounds the angles to 3 digits, which moves the positions by < 0.6 mm
    assert np.allclose(bluerov.allocation, flip @ ned, atol=1e-3)
    assert np.allclose(bluerov.allocation[2, 4:], 1.0)  # every vertical thruster lifts


def test_allocation_matrix_is_force_and_moment():
    matrix = allocation_matrix([[1.0, 0.0, 0.0]], [[0.0, 2.0, 0.0]])
    assert np.allclose(matrix[:, 0], [0, 1, 0, 0, 0, 1])  # unit force along y at x = 1: yaw moment 1


def _bad(**changes):
    data = tomllib.loads(builtin_vehicle_path("bluerov2_heavy").read_text())
    for key, value in changes.items():
        target = data
        *path, last = key.split(".")
        for part in path:
            target = target[int(part)] if part.isdigit() else target[part]
        target[int(last) if last.isdigit() else last] = value
    return data


def test_mount_outside_the_hull_is_a_warning():
    """A real arm often sits on a bracket ahead of the frame (issue 22: the tested BlueROV2's is at
    x = 0.25 m): allowed, with a warning that names the range."""
    for position, allowed in (([0.5, 0.0, -0.12], "[-0.2285, 0.2285]"), ([0.2, 0.0, -0.3], "[-0.127, 0.127]")):
        with pytest.warns(UserWarning, match=re.escape(allowed)):
            validate(VehicleSpec, _bad(**{"mount.position": position}), "bad.toml")


@pytest.mark.parametrize(
    ("changes", "field", "allowed"),
    [
        ({"mass": -1.0}, "mass", "greater than 0"),
        ({"inertia": [[1.0, 0.0], [0.0, 1.0]]}, "inertia", "give 3 principal values"),
        ({"allocation": [[0.0] * 8] * 5}, "allocation", "6 rows (X Y Z K M N) of 8 columns"),
        ({"allocation": [[0.0] * 7] * 6}, "allocation", "of 8 columns"),
        ({"thrusters.2.axis": [0.0, 0.0, 0.0]}, "thrusters.2.axis", "zero length"),
        ({"added_mass": [1.0, 2.0]}, "added_mass", "give 6 diagonal values"),
        ({"linear_damping": [1.0, 1.0, 1.0, 1.0, 1.0, -1.0]}, "linear_damping.5", "greater than or equal to 0"),
    ],
)
def test_bad_vehicle_files_name_the_field(changes, field, allowed):
    """What load_vehicle_spec does with a parsed file (read_mapping, then validate)."""
    with pytest.raises(ConfigError) as error:
        validate(VehicleSpec, _bad(**changes), "bad.toml")
    message = str(error.value)
    assert message.count("\n") == 0, message  # one problem, one line
    assert f"{field} =" in message and allowed in message, message


def test_unknown_vehicle_is_a_config_error():
    with pytest.raises(ConfigError, match="neither a built-in vehicle"):
        load_vehicle("no_such_vehicle")
    with pytest.raises(ConfigError, match="unknown key"):
        validate(VehicleSpec, {**_bad(), "masss": 1.0}, "v.toml")


# --- closed forms ---------------------------------------------------------------------------


def _simulate(plant, x, duration, u=None, dt=0.01):
    u = np.zeros(plant.n_arm + plant.n_thr) if u is None else u
    out = [x]
    for k in range(int(round(duration / dt))):
        x, _ = plant.step(k * dt, x, u, dt)
        out.append(x)
    return np.array(out)


def test_roll_period_matches_metacentric_closed_form(bluerov):
    """Neutrally buoyant, CB 1 cm above CG, no damping: small roll oscillates with
    T = 2 pi sqrt((I_xx + A_pp) / (rho g V GM_T)), GM_T = BG for a submerged body."""
    vehicle = _neutral(bluerov)
    plant = UVMSPlant(build_uvms(vehicle, None, gravity=G), Water(rho=RHO, gravity=G))
    tilt = 0.01
    q = plant.uvms.neutral()
    q[3:7] = [math.sin(tilt / 2), 0.0, 0.0, math.cos(tilt / 2)]
    states = _simulate(plant, plant.initial_state(q), 8.0)
    roll = 2.0 * np.arctan2(states[:, 3], states[:, 6])
    time = np.arange(len(roll)) * 0.01
    crossings = [
        time[k] - roll[k] * (time[k + 1] - time[k]) / (roll[k + 1] - roll[k])
        for k in range(len(roll) - 1)
        if roll[k] > 0.0 >= roll[k + 1]
    ]
    period = crossings[1] - crossings[0]
    bg = vehicle.cb[2] - vehicle.cg[2]
    expected = (
        2
        * math.pi
        * math.sqrt((vehicle.inertia[0, 0] + vehicle.added_mass[3, 3]) / (RHO * G * (vehicle.displaced_volume) * bg))
    )
    # the finite amplitude lengthens the period by tilt^2 / 16 = 6.25e-6 (measured 6.23e-6)
    assert abs(period / expected - 1.0) < 1e-5, (period, expected)
    assert abs(period / (expected * (1.0 + tilt**2 / 16.0)) - 1.0) < 1e-7
    assert np.max(np.abs(states[:, :3])) < 1e-9  # a pure couple: the CG stays put


def test_surge_decay_matches_closed_form(bluerov):
    """m u' = -(d_l + d_q |u|) u with m = mass + X_u' : u(t) = a u0 e^-at / (a + b u0 (1 - e^-at))."""
    vehicle = _neutral(bluerov, linear_damping=bluerov.linear_damping, quadratic_damping=bluerov.quadratic_damping)
    plant = UVMSPlant(build_uvms(vehicle, None, gravity=G), Water(rho=RHO, gravity=G))
    u0 = 1.0
    x = plant.initial_state(v=np.array([u0, 0, 0, 0, 0, 0]))
    states = _simulate(plant, x, 3.0)
    surge = states[:, plant.nq]
    mass = vehicle.mass + vehicle.added_mass[0, 0]
    a, b = vehicle.linear_damping[0] / mass, vehicle.quadratic_damping[0] / mass
    time = np.arange(len(surge)) * 0.01
    decay = np.exp(-a * time)
    expected = a * u0 * decay / (a + b * u0 * (1.0 - decay))
    assert np.max(np.abs(surge - expected)) < 1e-9
    assert np.max(np.abs(states[:, plant.nq + 1 : plant.nq + 6])) < 1e-12  # no coupling into the other DOF


def test_thrust_saturates_and_lags(bluerov):
    vehicle = dataclasses.replace(_neutral(bluerov), thrust_time_constant=0.1)
    plant = UVMSPlant(build_uvms(vehicle, None, gravity=G), Water(rho=RHO, gravity=G))
    command = np.array([100.0, -100.0, 10.0, 0.0, 0.0, 0.0, 0.0, 0.0])
    x = plant.initial_state()
    for k in range(5):
        x, info = plant.step(k * 0.01, x, command, 0.01)
    thrust = plant.split(x)[2]
    target = np.clip(command, vehicle.thrust_min, vehicle.thrust_max)
    assert target[0] == 51.5 and target[1] == -40.2
    assert np.allclose(thrust, target * (1.0 - math.exp(-0.05 / 0.1)), rtol=1e-12)
