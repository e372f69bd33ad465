"""A task from settings or a file (sinusoids in TOML, (t, q) samples in CSV), and the start on it."""

from __future__ import annotations

import numpy as np
import pytest

from hydroarm.config import ConfigError
from hydroarm.model.arm.loading import load_arm
from hydroarm.model.task.references import paper_reference
from hydroarm.model.task.task_file import SplineReference, TaskConfig, reference_for
from hydroarm.sim.experiment import ExperimentConfig, build_experiment, with_overrides

ARM = load_arm("paper")


def paper_coefficients():
    ref = paper_reference()
    return {"offset": ref.offset.tolist(), "cos_amp": ref.cos_amp.tolist(), "sin_amp": ref.sin_amp.tolist(),
            "omega": ref.omega.tolist()}  # fmt: skip


def test_the_default_task_is_the_arms():
    reference, x0 = reference_for(TaskConfig(), ARM)
    np.testing.assert_array_equal(reference.sample(1.3)[0], paper_reference().sample(1.3)[0])
    np.testing.assert_array_equal(x0, np.zeros(12))


def test_sinusoids_from_settings_and_from_a_toml_file_are_the_same_task(tmp_path):
    coefficients = paper_coefficients()
    from_settings, _ = reference_for(TaskConfig(kind="sinusoids", **coefficients), ARM)
    path = tmp_path / "task.toml"
    path.write_text("\n".join(f"{key} = {value}" for key, value in coefficients.items()))
    from_file, _ = reference_for(TaskConfig(kind="file", file=str(path)), ARM)
    times = np.linspace(0.0, 5.0, 11)
    for a, b, c in zip(from_settings.sample(times), from_file.sample(times), paper_reference().sample(times)):
        np.testing.assert_array_equal(a, c)
        np.testing.assert_array_equal(b, c)


def test_a_csv_is_splined_to_q_and_its_derivatives(tmp_path):
    """Samples of q = sin(t) every 0.01 s: the spline's q, q', q'' are sin, cos, -sin within the
    cubic spline's error (h^4, h^3, h^2 order)."""
    t = np.arange(0.0, 6.0, 0.01)
    q = np.sin(t)[:, None] * np.arange(1, 7)
    path = tmp_path / "task.csv"
    np.savetxt(path, np.column_stack([t, q]), delimiter=",", header="t,q1,q2,q3,q4,q5,q6", comments="")
    reference, x0 = reference_for(TaskConfig(kind="file", file=str(path), start="on_trajectory"), ARM)
    assert isinstance(reference, SplineReference)
    inner = np.linspace(0.5, 5.5, 23)
    position, velocity, acceleration = reference.sample(inner)
    scale = np.arange(1, 7)
    np.testing.assert_allclose(position, np.sin(inner)[:, None] * scale, atol=1e-8 * 6)
    np.testing.assert_allclose(velocity, np.cos(inner)[:, None] * scale, atol=1e-6 * 6)
    np.testing.assert_allclose(acceleration, -np.sin(inner)[:, None] * scale, atol=1e-3 * 6)
    np.testing.assert_allclose(x0, reference.state(0.0))  # started on the trajectory
    assert abs(x0[6] - 1.0) < 1e-4  # q1'(0) = cos 0
    late = reference.sample(100.0)  # beyond the samples: held at the end
    np.testing.assert_allclose(late[0], reference.sample(t[-1])[0])


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("t,q1,q2,q3,q4,q5,q6\n0,0,0,0,0,0,0\n1,0,0,0,0,0,0\n", "2 samples: a spline needs at least 4"),
        ("\n".join(f"{x},0,0,0,0,0,0" for x in (0, 1, 0.5, 2, 3)), "times must increase strictly"),
        ("\n".join(f"{x},0,0,0" for x in (0, 1, 2, 3)), "4 columns: give t and one q per joint"),
        ("0,0,0,0,0,0,0\n1,x,0,0,0,0,0\n", "line 2: not numbers"),
        ("\n".join(f"{x},0,0,0,0,0,nan" for x in (0, 1, 2, 3)), "values must be finite"),
    ],
)
def test_a_bad_csv_is_one_clear_message(tmp_path, text, message):
    path = tmp_path / "task.csv"
    path.write_text(text)
    with pytest.raises(ConfigError, match=message):
        reference_for(TaskConfig(kind="file", file=str(path)), ARM)


def test_bad_task_settings_are_refused_before_a_run(tmp_path):
    with pytest.raises(ConfigError, match="needs task.file"):
        with_overrides(ExperimentConfig(), {"task.kind": "file"})
    wrong = {**paper_coefficients(), "offset": [0.0] * 5}
    config = with_overrides(
        ExperimentConfig(), {"task.kind": "sinusoids", **{f"task.{k}": v for k, v in wrong.items()}}
    )
    with pytest.raises(ConfigError, match="offset has 5 values: give one per joint"):
        build_experiment(config, "idmpc")
    with pytest.raises(ConfigError, match="no such file"):
        build_experiment(with_overrides(ExperimentConfig(), {"task.kind": "file", "task.file": "nope.csv"}), "idmpc")


def test_a_run_on_its_own_trajectory_starts_without_error(tmp_path):
    t = np.linspace(0.0, 3.0, 301)
    q = np.column_stack([0.5 * np.sin((j + 1) * t) for j in range(6)])
    path = tmp_path / "task.csv"
    np.savetxt(path, np.column_stack([t, q]), delimiter=",")
    config = with_overrides(
        ExperimentConfig(duration=1.0),
        {"task.kind": "file", "task.file": str(path), "task.start": "on_trajectory"},
    )
    traj = build_experiment(config, "idmpc").run()
    np.testing.assert_allclose(traj.q[0], traj.q_ref[0], atol=1e-12)
    assert np.max(np.abs(traj.q - traj.q_ref)) < 0.05
