"""The benchmark suite bench/hydroarm_bench (quick mode: shape and sanity, no timing
thresholds; importable through pytest's ``pythonpath = ["bench"]``) and the compiled
kernels behind its numbers, each against the plain-NumPy twin it replaces."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

import hydroarm
from hydroarm.control import mpc as mpc_module
from hydroarm.control.gp import _batched as gp_module
from hydroarm.model.arm.plant import PlantConfig, UnderwaterPlant
from hydroarm.model.dynamics.nominal import NominalModel
from hydroarm.model.task.references import paper_reference
from hydroarm.model.water.morison import CurrentConfig, Water
from hydroarm_bench import growth_exponent, run_benchmarks, stats_ms, validate_report
from hydroarm_bench import mpc_peers as mpc_peers_module
from hydroarm_bench.control_steps import mpc_snapshot_hook
from hydroarm_bench.loop import closed_loop
from hydroarm_bench.stats import missing

HEADLINE = ("speedup_vs_do_mpc", "speedup_vs_cvxpy", "gp_speedup_vs_sklearn")


# --------------------------------------------------------------------------------------
# The quick benchmark
# --------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def quick_report(tmp_path_factory):
    out = tmp_path_factory.mktemp("bench")
    report = run_benchmarks(out, quick=True)
    return out, report


@pytest.mark.slow
def test_quick_benchmark_writes_json_and_markdown(quick_report):
    out, report = quick_report
    on_disk = json.loads((out / "bench.json").read_text())
    assert on_disk["gp_mpc_step_ms"] == report["gp_mpc_step_ms"]
    markdown = (out / "bench.md").read_text()
    for heading in ("## Targets", "## 1. Control step", "## 2. Peers", "## 3. Scaling", "## 4. Throughput"):
        assert heading in markdown


@pytest.mark.slow
def test_quick_benchmark_json_is_valid(quick_report):
    _, report = quick_report
    assert validate_report(report) == []
    for key in ("gp_idmpc_step_ms", "gp_mpc_step_ms", "mpc_step_ms", "smc_step_ms"):
        assert set(report[key]) == {"median", "p90", "p99", "max"}
        assert all(value > 0 for value in report[key].values())
    assert report["paper_scenario_wall_s"] > 0
    assert report["blas_threads"] == 1
    for key in HEADLINE:  # a number, or null with the reason (peer not installed)
        assert report[key] is None and report[f"{key}_reason"] or report[key] > 0


@pytest.mark.slow
def test_gp_mpc_total_is_at_least_each_part(quick_report):
    _, report = quick_report
    parts = report["breakdown"]["GP-MPC"]
    assert {"observe", "gp", "linearise", "riccati", "qp_update", "qp_solve", "compute", "total"} <= set(parts)
    for key, row in parts.items():
        assert row["n"] >= 200
        for stat in ("median", "p90", "p99", "max"):
            assert 0 < row[stat] <= parts["total"][stat], (key, stat)


@pytest.mark.slow
def test_peers_that_ran_give_the_same_answers(quick_report):
    _, report = quick_report
    for label, peer in report["peers"]["mpc"]["peers"].items():
        if peer["available"]:
            assert peer["first_torque_max_abs_diff_nm"] <= 1e-4, label
        else:
            assert peer["reason"], label
    sklearn = report["peers"]["gp"]["peers"]["sklearn"]
    if sklearn["available"]:
        assert sklearn["mean_at_our_theta_max_abs_diff"] <= 1e-6
    plant = report["peers"]["plant"]
    assert plant["plant_step_max_abs_diff_vs_reference"] == 0.0


@pytest.mark.slow
def test_scaling_rows_and_exponents(quick_report):
    _, report = quick_report
    scaling = report["scaling"]
    assert [row["window"] for row in scaling["gp_window"]["rows"]] == [10, 20, 50, 100, 200]
    assert [row["horizon"] for row in scaling["mpc_horizon"]["rows"]] == [5, 10, 20, 40]
    assert len(scaling["plant_quadrature"]["rows"]) >= 4
    for section in scaling.values():
        assert math.isfinite(section["growth_exponent"])


@pytest.mark.slow
def test_validation_catches_bad_documents(quick_report):
    _, report = quick_report
    broken = json.loads(json.dumps(report))
    broken["gp_mpc_step_ms"]["median"] = -1.0
    broken["speedup_vs_do_mpc"] = None
    broken.pop("speedup_vs_do_mpc_reason", None)
    broken["breakdown"]["GP-MPC"]["gp"]["max"] = broken["breakdown"]["GP-MPC"]["total"]["max"] * 2
    problems = validate_report(broken)
    assert any("gp_mpc_step_ms" in p for p in problems)
    assert any("speedup_vs_do_mpc" in p for p in problems)
    assert any("exceeds total" in p for p in problems)


def test_helpers():
    assert missing("surely_not_an_installed_module_xyz").startswith("not installed")
    assert missing("numpy") is None
    assert growth_exponent([10, 20, 40], [1.0, 4.0, 16.0]) == pytest.approx(2.0)
    row = stats_ms([0.001] * 10)
    assert row["median"] == pytest.approx(1.0) and row["n"] == 10


def test_a_section_alone_says_its_machine_and_load():
    """``--only`` files: the .md's first line names the load; above the core count it says so."""
    from hydroarm_bench.suite import section_markdown

    machine = {"cpu_count": 2, "cpu_model": "x"}
    report = {"date": "d", "machine": machine, "load_average": [[7.5, 1, 1], [8.6, 1, 1]], "s": {}}
    text = section_markdown(report, "s", lambda section: "\n## body\n")
    first = text.splitlines()[0]
    assert "load average 7.5 at the start and 8.6 at the end" in first and "a loaded machine" in first
    assert text.endswith("## body\n")
    report["load_average"] = [[0.5, 1, 1], [1.5, 1, 1]]
    assert "a loaded machine" not in section_markdown(report, "s", lambda section: "")


def test_the_flagship_section_times_the_whole_chain_of_the_controller_flagship_resolves_to():
    """Quick mode: the flagship (what ``--controller flagship`` runs) and IDMPC on the paper task,
    every observed step timed; a step's wall time holds its compute and its observe."""
    from hydroarm.control.registry import ALIASES
    from hydroarm_bench.flagship import bench_flagship, render_flagship
    from hydroarm_bench.loop import TimedController, paper_experiment

    section = bench_flagship(quick=True)
    assert section["flagship"] == ALIASES["flagship"] and section["peer"] == "IDMPC"
    rows = section["cases"]["paper"]
    for name in (section["flagship"], "IDMPC"):
        assert rows[name]["step"]["n"] == 100 and rows[name]["step_cpu"]["n"] == 100  # 1 s: 100 steps
        assert 0.0 < rows[name]["step"]["median"] <= rows[name]["step"]["max"]
    assert rows["median_ratio"] == rows[section["flagship"]]["step"]["median"] / rows["IDMPC"]["step"]["median"]
    assert f"| paper | {section['flagship']} |" in render_flagship(section)
    experiment = paper_experiment("IDMPC", 0.2)
    timed = TimedController(experiment.controller)
    experiment.controller = timed
    experiment.run(0)
    steps = len(timed.observe_s)
    assert len(timed.wall_s) >= steps > 0
    assert all(wall >= observe for wall, observe in zip(timed.wall_s, timed.observe_s, strict=False))


# --------------------------------------------------------------------------------------
# Compiled kernels equal their plain-NumPy twins (*_numpy)
# --------------------------------------------------------------------------------------
def _window(rng, n=10, d=12, o=6):
    X = rng.normal(size=(n, d))
    Y = 50.0 * rng.normal(size=(o, n))
    window = gp_module._Window(X, Y, np.zeros(o), np.ones(o))
    log_theta = np.log(rng.uniform(0.3, 5.0, size=(o, d + 2)))
    log_theta[:, 0] = np.log(rng.uniform(10.0, 300.0, size=o))
    log_theta[:, 1] = np.log(rng.uniform(1e-5, 1e-1, size=o))
    return window, Y, log_theta


@pytest.mark.parametrize("seed", range(5))
@pytest.mark.parametrize("with_gradient", [True, False])
def test_gp_evaluate_kernel_equals_numpy_twin(seed, with_gradient):
    window, Y, log_theta = _window(np.random.default_rng(seed))
    sn2 = np.exp(log_theta[:, 1])
    fast = gp_module._evaluate(window, Y, log_theta, sn2, 1e-10, 4, with_gradient)
    reference = gp_module._evaluate_numpy(window, Y, log_theta, sn2, 1e-10, 4, with_gradient)
    for field in ("lml", "grad", "half_trace_w", "alpha", "linv"):
        a, b = getattr(fast, field), getattr(reference, field)
        if b is None:
            assert a is None
            continue
        np.testing.assert_allclose(a, b, rtol=1e-9, atol=1e-9 * np.abs(b).max(), err_msg=field)
    np.testing.assert_array_equal(fast.ok, reference.ok)
    np.testing.assert_array_equal(fast.extra_diag, reference.extra_diag)
    cached = gp_module._evaluate(
        window, Y, log_theta, sn2, 1e-10, 4, True, cached=(reference.linv, reference.extra_diag)
    )
    np.testing.assert_allclose(cached.lml, reference.lml, rtol=1e-12)


def test_gp_evaluate_runs_the_jitter_ladder_when_a_cholesky_fails():
    X = np.zeros((4, 2))  # identical inputs: K = sf2 * ones, singular without noise
    Y = np.ones((2, 4))
    window = gp_module._Window(X, Y, np.zeros(2), np.ones(2))
    log_theta = np.zeros((2, 4))
    sn2 = np.zeros(2)
    fast = gp_module._evaluate(window, Y, log_theta, sn2, 0.0, 4, True)
    reference = gp_module._evaluate_numpy(window, Y, log_theta, sn2, 0.0, 4, True)
    np.testing.assert_array_equal(fast.extra_diag, reference.extra_diag)
    assert (fast.extra_diag > 0).all()
    # K = 1 1^T + e I (e the ladder's first step, 1e-10): |K| = e^(n-1) (n + e), 1^T K^-1 1 = n / (n + e)
    n, e = 4, float(fast.extra_diag[0])
    closed = -0.5 * n / (n + e) - 0.5 * ((n - 1) * np.log(e) + np.log(n + e)) - 0.5 * n * np.log(2 * np.pi)
    # the pivots after the first are e = 1e-10 left from 1 + e - 1: each carries eps / e ~ 2e-6
    # relative error in any Cholesky (LAPACK's too), about 1e-7 absolute in the LML
    np.testing.assert_allclose(fast.lml, closed, rtol=2e-8)
    # the NumPy twin forms K^-1 (condition number 4e10): it agrees to what that leaves
    np.testing.assert_allclose(fast.lml, reference.lml, rtol=1e-7)


@pytest.mark.parametrize("seed", range(3))
def test_gp_predict_kernel_equals_numpy_twin(seed):
    rng = np.random.default_rng(seed)
    window, Y, log_theta = _window(rng)
    evaluation = gp_module._evaluate_numpy(window, Y, log_theta, np.exp(log_theta[:, 1]), 1e-10, 4, False)
    X_star = rng.normal(size=(3, window.X.shape[1]))
    fast = gp_module._predict_with_factor(window, X_star, log_theta, evaluation.linv, evaluation.alpha)
    reference = gp_module._predict_with_factor_numpy(window, X_star, log_theta, evaluation.linv, evaluation.alpha)
    for a, b in zip(fast, reference):
        np.testing.assert_allclose(a, b, rtol=1e-9, atol=1e-9 * np.abs(b).max())


@pytest.fixture(scope="module")
def arm():
    return hydroarm.load_arm("paper")


def _linearised_window(arm, start: float, horizon: int = 10, period: float = 0.01):
    reference = paper_reference()
    points = []
    for k in range(horizon + 1):
        q, v, a = reference.sample(start + k * period)
        tau = arm.inverse_dynamics(q, v, a)
        A, B, x_next = NominalModel(arm).linearise(q, v, tau, period, "euler")
        points.append((A, B, x_next, np.concatenate([q, v])))
    A = np.stack([p[0] for p in points[:horizon]])
    B = np.stack([p[1] for p in points[:horizon]])
    c = np.stack([p[2] for p in points[:horizon]]) - np.stack([p[3] for p in points[1:]])
    return A, B, c


@pytest.mark.parametrize("start", [0.0, 1.3, 4.7])
def test_condense_kernel_equals_numpy_twin(arm, start):
    A, B, c = _linearised_window(arm, start)
    rng = np.random.default_rng(int(start * 10))
    q_diag = np.concatenate([np.full(6, 300.0), np.full(6, 0.01)])
    r_diag = np.full(6, 0.1)
    root = rng.normal(size=(12, 12))
    P = root @ root.T + 100.0 * np.eye(12)
    e0 = rng.normal(size=12) * 0.1
    fast = mpc_module.condense(A, B, c, q_diag, r_diag, P, e0)
    twin = mpc_module.condense_numpy(A, B, c, q_diag, r_diag, P, e0)
    for field in ("H", "g", "prediction", "free"):
        a, b = getattr(fast, field), getattr(twin, field)
        np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-12 * np.abs(b).max(), err_msg=field)
    np.testing.assert_array_equal(fast.H, fast.H.T)


def test_linearisation_fill_is_bit_identical(arm):
    reference = paper_reference()
    for t in (0.0, 0.37, 6.1):
        q, v, a = reference.sample(t)
        tau = arm.inverse_dynamics(q, v, a)
        nominal = NominalModel(arm)
        for fixed in (False, True):
            fast_a, fast_b = np.full((12, 12), 3.0), np.full((12, 6), 3.0)
            ref_a, ref_b = fast_a.copy(), fast_b.copy()
            x_fast = nominal.linearise_into(q, v, tau, 0.01, fast_a, fast_b, "euler", constant_blocks_set=fixed)
            x_ref = nominal.linearise_into_numpy(q, v, tau, 0.01, ref_a, ref_b, constant_blocks_set=fixed)
            np.testing.assert_array_equal(fast_a, ref_a)
            np.testing.assert_array_equal(fast_b, ref_b)
            np.testing.assert_array_equal(x_fast, x_ref)


@pytest.mark.parametrize(
    "water",
    [
        Water(),
        Water(current=CurrentConfig(model="none")),
        Water(
            current=CurrentConfig(
                model="uniform", mean=[0.2, -0.1, 0.0], amplitude=[0.1, 0.0, 0.05], frequency_hz=1.0, phase=0.3
            )
        ),
        Water().off(),
    ],
    ids=["paper", "still", "uniform", "off"],
)
@pytest.mark.parametrize("friction", [0.0, 0.05])
def test_compiled_plant_step_is_bit_identical_to_the_numpy_twin(arm, water, friction):
    plant = UnderwaterPlant(arm, water, PlantConfig(friction=friction))
    x0 = np.concatenate([[0.3, -0.8, 1.2, 0.4, -0.6, 0.2], [1.0, -0.5, 0.8, 2.0, -1.5, 3.0]])
    u = np.array([20.0, -40.0, 10.0, 2.0, -1.0, 0.5])
    for t, dt in ((0.37, 0.01), (1.0, 0.0035), (2.0, 0.02)):
        x_fast, info_fast = plant.step(t, x0, u, dt)
        x_ref, info_ref = plant.step_numpy(t, x0, u, dt)
        np.testing.assert_array_equal(x_fast, x_ref)
        np.testing.assert_array_equal(info_fast.disturbance, info_ref.disturbance)
        np.testing.assert_array_equal(info_fast.disturbance_start, info_ref.disturbance_start)
    np.testing.assert_array_equal(x0[:3], [0.3, -0.8, 1.2])  # the input is not modified


def test_a_missing_peer_is_skipped_with_a_reason(monkeypatch):
    """CI installs no do-mpc or GPyTorch: their rows must say why instead of failing."""
    snapshots = []
    traj, _, _, controller = closed_loop("MPC", 0.05, 0, mpc_snapshot_hook(snapshots))
    recorded = {"MPC": {"traj": traj, "controller": controller, "snapshots": snapshots}}
    monkeypatch.setattr(mpc_peers_module, "missing", lambda *modules: f"not installed: {', '.join(modules)}")
    report = mpc_peers_module.bench_mpc_peers(recorded, stats_ms(traj.timings["total"]), quick=True)
    assert report["problem"]["problems"] == len(snapshots) == 5
    for label, peer in report["peers"].items():
        assert peer == {"available": False, "reason": peer["reason"]} and "not installed" in peer["reason"], label
    assert report["ours_qp_vs_controller_torque_max_abs_diff_nm"] < 1e-9


def test_the_suite_builds_its_runs_with_build_experiment():
    """The benchmark runs what ``hydroarm run`` runs: the paper scenario of build_experiment."""
    from hydroarm.sim.experiment import ExperimentConfig, run_experiment

    traj, observe_s, _, controller = closed_loop("SMC", 0.05, 0)
    expected = run_experiment(ExperimentConfig(duration=0.05), "SMC", seed=0)
    assert controller.name == "SMC" and len(observe_s) == len(traj.t)
    np.testing.assert_array_equal(traj.x, expected.x)
    np.testing.assert_array_equal(traj.u, expected.u)


@pytest.mark.parametrize("inner_step", [None, 1e-3])
def test_compiled_nominal_rk4_step_is_bit_identical(arm, inner_step):
    nominal = NominalModel(arm, inner_step=inner_step)
    rng = np.random.default_rng(3)
    for _ in range(10):
        y, u = rng.normal(size=12), 50.0 * rng.normal(size=6)
        np.testing.assert_array_equal(nominal.predict(y, u, 0.01), nominal.predict_numpy(y, u, 0.01))


# --------------------------------------------------------------------------------------
# `hydroarm bench`: a thin entry to bench/ in a source checkout
# --------------------------------------------------------------------------------------
def _fake_checkout(monkeypatch, tmp_path, suite: str | None):
    """hydroarm imported from ``tmp_path/src/hydroarm``; ``tmp_path/bench/hydroarm_bench`` holds ``suite``."""
    monkeypatch.setattr(hydroarm, "__file__", str(tmp_path / "src" / "hydroarm" / "__init__.py"))
    if suite is not None:
        package = tmp_path / "bench" / "hydroarm_bench"
        package.mkdir(parents=True)
        (package / "__init__.py").write_text("")
        (package / "__main__.py").write_text(suite)


def test_cli_bench_runs_the_suite_of_the_checkout_and_forwards_its_exit_code(monkeypatch, tmp_path):
    from typer.testing import CliRunner

    from hydroarm.cli import app

    record = tmp_path / "args.json"
    suite = f"import json, sys\njson.dump(sys.argv[1:], open({str(record)!r}, 'w'))\nsys.exit(3)\n"
    _fake_checkout(monkeypatch, tmp_path, suite)
    result = CliRunner().invoke(app, ["bench", "--out", str(tmp_path / "out"), "--quick"])
    assert result.exit_code == 3, result.output
    assert json.loads(record.read_text()) == ["--out", str(tmp_path / "out"), "--quick"]


def test_cli_bench_without_the_bench_folder_says_where_the_suite_lives(monkeypatch, tmp_path):
    from typer.testing import CliRunner

    from hydroarm.cli import app

    _fake_checkout(monkeypatch, tmp_path, None)
    result = CliRunner().invoke(app, ["bench", "--out", str(tmp_path / "out")])
    assert result.exit_code == 2
    assert "the benchmark suite lives in the source repository's bench/ folder" in result.output
    assert not (tmp_path / "out").exists()


def test_the_suite_is_not_in_the_package():
    import importlib.util

    assert importlib.util.find_spec("hydroarm.benchmark") is None
