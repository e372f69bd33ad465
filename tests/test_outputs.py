"""Outputs you can trust (issue 16): safe file names and run ids, strict JSON, and output
folders that refuse results of other settings unless --overwrite (which leaves nothing stale),
while the same command still resumes."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from hydroarm.cli import app
from hydroarm.sim.experiment import ExperimentConfig
from hydroarm.studies.executor import SerialExecutor
from hydroarm.studies.outputs import MANIFEST, OutputConflict, dumps, slug, strict
from hydroarm.studies.reproduce import RunSpec, plan_runs
from hydroarm.studies.sweep import plan_sweep, run_sweep, validate_sweep

RUNNER = CliRunner()
SAFE = re.compile(r"^[a-z0-9._-]+$")


def _no_constant(name: str):
    raise ValueError(f"not strict JSON: {name}")


def strict_json(text: str):
    """``json.loads`` that refuses NaN, Infinity and -Infinity."""
    return json.loads(text, parse_constant=_no_constant)


def one_line_error(output: str) -> str:
    lines = [line for line in output.splitlines() if line.startswith("error:")]
    assert len(lines) == 1, output
    return lines[0]


# --- names --------------------------------------------------------------------------------


def test_slug_is_lowercase_safe_and_readable():
    assert slug("ablation/control period T (s)=0.02__MPC__seed0") == "ablation-control-period-t-s-0.02__mpc__seed0"
    assert slug("GP-IDMPC+KF") == "gp-idmpc-kf"
    assert slug("state+nominal") == "state-nominal"
    assert slug("  Ünïcode / spaces  ") == "n-code-spaces"


def test_reproduce_run_files_have_safe_unique_names():
    config = ExperimentConfig()
    assert RunSpec("ablation/control period T (s)=0.02", "MPC", 0, config).key == (
        "ablation-control-period-t-s-0.02__mpc__seed0"
    )
    assert RunSpec("clean", "GP-IDMPC+KF", 0, config).key == "clean__gp-idmpc-kf__seed0"
    keys = [spec.key for spec in plan_runs(config, 2, ablation=True)]
    assert len(set(keys)) == len(keys) and all(SAFE.match(k) for k in keys)
    assert "ablation-gp-input-features-state-nominal__gp-mpc__seed0" in keys


def test_sweep_run_ids_are_safe_and_say_controller_and_seed():
    sweep = validate_sweep({"controllers": ["GP-MPC", "smc"], "seeds": [3], "parameters": {"mpc.r": [0.1]}})
    ids = [row.id for row in plan_sweep(sweep).rows]
    assert all(SAFE.match(i) for i in ids)
    assert ids[0].startswith("gp-mpc__seed3__") and ids[1].startswith("smc__seed3__")


# --- strict JSON ----------------------------------------------------------------------------


def test_strict_replaces_nan_and_infinities_with_null():
    value = {"a": [1.0, float("nan"), np.inf], "b": np.float64(-np.inf), "c": (np.int64(2), np.bool_(True))}
    assert strict(value) == {"a": [1.0, None, None], "b": None, "c": [2, True]}
    assert strict_json(dumps(value)) == {"a": [1.0, None, None], "b": None, "c": [2, True]}


@pytest.mark.slow
def test_a_one_second_run_writes_strict_json(tmp_path):
    """Ep_steady (t > 2 s) and a time_to_band are undefined in a 1 s run: null, not NaN."""
    out = tmp_path / "run"
    result = RUNNER.invoke(app, ["run", "--controller", "smc", "--set", "duration=1.0", "--out", str(out), "--json"])
    assert result.exit_code == 0, result.output
    printed = strict_json(result.output.strip().splitlines()[-1])
    written = strict_json((out / "metrics.json").read_text())
    assert printed == written and written["Ep_steady"] == [None] * 6


# --- output folders: run ---------------------------------------------------------------------


@pytest.mark.slow
def test_run_refuses_a_folder_of_other_settings_and_overwrite_leaves_nothing_stale(tmp_path):
    out = tmp_path / "run1"
    args = ["run", "--set", "duration=0.1", "--out", str(out)]
    assert RUNNER.invoke(app, [*args, "--controller", "gp-mpc"]).exit_code == 0
    assert (out / "disturbance.png").is_file() and (out / MANIFEST).is_file()
    assert RUNNER.invoke(app, [*args, "--controller", "gp-mpc"]).exit_code == 0  # the same run: fine
    before = {p.name: p.stat().st_mtime_ns for p in out.iterdir()}
    refused = RUNNER.invoke(app, [*args, "--controller", "smc"])
    assert refused.exit_code == 2
    line = one_line_error(refused.output)
    assert str(out) in line and "--overwrite" in line and "GP-MPC" in line
    assert {p.name: p.stat().st_mtime_ns for p in out.iterdir()} == before  # nothing touched
    assert RUNNER.invoke(app, [*args, "--controller", "smc", "--overwrite"]).exit_code == 0
    assert not (out / "disturbance.png").exists()  # GP-MPC's figure is gone with its run
    assert json.loads((out / MANIFEST).read_text())["settings"]["controller"] == "SMC"


def test_a_folder_with_results_but_no_manifest_is_refused(tmp_path):
    (tmp_path / "metrics.json").write_text("{}")
    (tmp_path / "notes.txt").write_text("mine")
    result = RUNNER.invoke(app, ["run", "--set", "duration=0.1", "--out", str(tmp_path)])
    assert result.exit_code == 2 and "metrics.json" in one_line_error(result.output)


# --- output folders: reproduce ------------------------------------------------------------------


@pytest.mark.slow
@pytest.mark.subprocess  # the runs go to worker processes
@pytest.mark.filterwarnings("error::RuntimeWarning")  # a 0.3 s run has no samples after 1 s: no 'Mean of empty slice'
def test_reproduce_refuses_other_settings_overwrite_clears_the_ablation_and_the_same_command_resumes(tmp_path):
    out = tmp_path / "results"
    # 2 replicas (the replicated rows' aggregation still runs): 142 + 32 runs instead of 250 + 56
    short = ["--set", "duration=0.3", "--seeds", "1", "--replicas", "2", "--workers", "2"]
    full = RUNNER.invoke(app, ["reproduce", "--out", str(out), *short, "--ablation"])
    assert full.exit_code == 0, full.output
    assert (out / "ablation.md").is_file() and list((out / "runs").glob("ablation-*"))

    # The tutorial's `reproduce --out results --quick` after a full run: refused, nothing touched.
    before = {str(p): p.stat().st_mtime_ns for p in out.rglob("*")}
    quick = RUNNER.invoke(app, ["reproduce", "--out", str(out), "--quick"])
    assert quick.exit_code == 2
    line = one_line_error(quick.output)
    assert str(out) in line and "--overwrite" in line and "reproduce" in line
    assert {str(p): p.stat().st_mtime_ns for p in out.rglob("*")} == before

    # Other settings with --overwrite: no ablation file of the old study is left behind.
    again = ["reproduce", "--out", str(out), *short, "--no-ablation"]
    assert RUNNER.invoke(app, again).exit_code == 2
    result = RUNNER.invoke(app, [*again, "--overwrite", "--json"])
    assert result.exit_code == 0, result.output
    assert not list(out.glob("ablation*")) and not list((out / "runs").glob("ablation-*"))
    assert "## Ablation" not in (out / "report.md").read_text()

    # Strict JSON: E_p after 2 s of a 0.3 s run is undefined.
    printed = strict_json(result.output[result.output.index("{") :])
    metrics, summary = (strict_json((out / name).read_text()) for name in ("metrics.json", "summary.json"))
    assert printed == metrics == {case: summary[case] for case in ("clean", "noisy")}
    assert metrics["clean"]["SMC"]["Ep_steady"] == [None] * 6
    assert "summary.json" in summary["files"] and "summary.json" in (out / "report.md").read_text()

    # The same command again resumes: no run is recomputed.
    runs = {p.name: p.stat().st_mtime_ns for p in (out / "runs").iterdir()}
    assert RUNNER.invoke(app, again).exit_code == 0
    assert {p.name: p.stat().st_mtime_ns for p in (out / "runs").iterdir()} == runs


# --- output folders: sweep ------------------------------------------------------------------------


def _sweep(**change):
    data = {"controllers": ["MPC"], "seeds": 1, "base": {"duration": 0.1}, "parameters": {"mpc.r": [0.01, 0.1]}}
    return validate_sweep({**data, **change})


def test_sweep_resumes_extends_and_refuses_another_sweep(tmp_path):
    first = run_sweep(_sweep(), tmp_path, executor=SerialExecutor())
    assert first["ran"] == 2
    assert run_sweep(_sweep(), tmp_path, executor=SerialExecutor())["reused"] == 2  # the same sweep
    extended = run_sweep(_sweep(seeds=2), tmp_path, executor=SerialExecutor())  # more seeds: extends
    assert extended["reused"] == 2 and extended["ran"] == 2
    other = _sweep(parameters={"gp.window": [5, 10]}, controllers=["GP-MPC"])
    with pytest.raises(OutputConflict, match=re.escape(f"--out '{tmp_path}' holds the results of hydroarm sweep")):
        run_sweep(other, tmp_path, executor=SerialExecutor())
    assert (tmp_path / "ep_by_mpc_r.png").is_file()
    replaced = run_sweep(other, tmp_path, executor=SerialExecutor(), overwrite=True)
    assert replaced["ran"] == 2 and replaced["reused"] == 0
    assert not (tmp_path / "ep_by_mpc_r.png").exists()  # the old sweep's plot
    assert sorted(p.stem for p in (tmp_path / "runs").iterdir()) == sorted(r["id"] for r in _rows(tmp_path))


def _rows(out: Path) -> list[dict]:
    return json.loads((out / "sweep.json").read_text())["rows"]


@pytest.mark.slow
@pytest.mark.subprocess  # the runs go to a worker process
def test_a_sweep_of_one_second_runs_writes_strict_json(tmp_path):
    """time_to_band and the robustness bound (after 2 s) are undefined in 1 s runs."""
    sweep = tmp_path / "s.toml"
    sweep.write_text('controllers = ["SMC"]\n[base]\nduration = 1.0\n[parameters]\n"mpc.r" = [0.1]\n')
    out = tmp_path / "out"
    result = RUNNER.invoke(app, ["sweep", str(sweep), "--out", str(out), "--workers", "1", "--json"])
    assert result.exit_code == 0, result.output
    strict_json(result.output[result.output.index("{") :])
    for path in [out / "summary.json", out / "sweep.json", out / MANIFEST, *(out / "runs").glob("*.json")]:
        strict_json(path.read_text())
