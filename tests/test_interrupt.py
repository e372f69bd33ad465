"""Long runs lose nothing (issue 7, item 4): ``hydroarm reproduce`` and ``hydroarm
sweep`` interrupted by SIGINT (Ctrl-C: the whole process group) or SIGTERM (a
scheduler: the main process) exit 130 / 143, leave every finished run on disk
readable, and the same command resumes without recomputing them."""

from __future__ import annotations

import json
import multiprocessing
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from hydroarm.sim.experiment import ExperimentConfig
from hydroarm.sim.runner import Trajectory
from hydroarm.studies.executor import LocalExecutor, run_tasks
from hydroarm.studies.reproduce import RunSpec, TrajectoryFiles, run_one

pytestmark = [pytest.mark.slow, pytest.mark.subprocess]

TIMEOUT = 300  # s: generous for a shared 2-core machine; the commands take ~5-40 s


def _default_sigint() -> None:
    # A background job of a non-interactive shell inherits SIGINT ignored; a user's
    # terminal does not. Test the user's case.
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def start(args: list[str], cwd: Path) -> subprocess.Popen:
    env = dict(os.environ, MPLBACKEND="Agg", OMP_NUM_THREADS="1")
    return subprocess.Popen(
        [sys.executable, "-m", "hydroarm.cli", *args], cwd=cwd, env=env, stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT, start_new_session=True, preexec_fn=_default_sigint,
    )  # fmt: skip


def wait_for_files(pattern: str, folder: Path, count: int, process: subprocess.Popen) -> None:
    deadline = time.monotonic() + TIMEOUT
    while len(list(folder.glob(pattern))) < count:
        assert process.poll() is None, process.communicate()[0].decode()[-2000:]
        assert time.monotonic() < deadline, "no finished run appeared"
        time.sleep(0.1)


def interrupt(process: subprocess.Popen, sig: int, whole_group: bool) -> tuple[int, str]:
    if whole_group:
        os.killpg(process.pid, sig)
    else:
        process.send_signal(sig)
    output = process.communicate(timeout=TIMEOUT)[0].decode()
    return process.returncode, output


def resume(args: list[str], cwd: Path) -> None:
    """Run the same command again, to completion."""
    result = subprocess.run(
        [sys.executable, "-m", "hydroarm.cli", *args], cwd=cwd, capture_output=True, timeout=TIMEOUT,
        env=dict(os.environ, MPLBACKEND="Agg"),
    )  # fmt: skip
    assert result.returncode == 0, result.stderr.decode()[-2000:]


def snapshot(files: list[Path]) -> dict[str, tuple[int, int]]:
    return {f.name: (f.stat().st_ino, f.stat().st_mtime_ns) for f in files}


def test_module_entry_point_exists():
    """The tests start the CLI as ``python -m hydroarm.cli`` (no console script needed)."""
    result = subprocess.run([sys.executable, "-m", "hydroarm.cli", "--help"], capture_output=True, timeout=TIMEOUT)
    assert result.returncode == 0 and b"reproduce" in result.stdout


def test_reproduce_interrupted_by_ctrl_c_resumes(tmp_path):
    # one noisy seed and no replicas: 28 runs instead of the quick study's 54, as many as the
    # interrupt needs (2 finished, more left to resume)
    args = ["reproduce", "--quick", "--seeds", "1", "--replicas", "1", "--out", "out", "--workers", "2"]
    process = start(args, tmp_path)
    runs = tmp_path / "out" / "runs"
    wait_for_files("*.npz", runs, 2, process)
    code, output = interrupt(process, signal.SIGINT, whole_group=True)
    assert code == 130, output[-2000:]
    assert "Traceback" not in output and "resume" in output
    finished = sorted(runs.glob("*.npz"))
    assert len(finished) >= 2
    for path in finished:  # every finished run is readable
        assert Trajectory.load(path).meta["steps"] > 0
    assert not (tmp_path / "out" / "metrics.json").exists()
    before = snapshot(finished)

    resume(args, tmp_path)
    after = snapshot(sorted(runs.glob("*.npz")))
    assert {name: after[name] for name in before} == before  # not recomputed, not rewritten
    assert len(after) > len(before)
    metrics = json.loads((tmp_path / "out" / "metrics.json").read_text())
    assert set(metrics) >= {"clean", "noisy"}


SWEEP = """
controllers = ["SMC", "MPC"]
seeds = 2
mode = "grid"

[base]
duration = 1.0

[parameters]
"water.current.scale" = [0.0, 1.0, 2.0, 3.0]
"""


@pytest.mark.parametrize("sig, whole_group, code", [(signal.SIGTERM, False, 143), (signal.SIGINT, True, 130)])
def test_sweep_interrupted_resumes(tmp_path, sig, whole_group, code):
    (tmp_path / "sweep.toml").write_text(SWEEP)
    args = ["sweep", "sweep.toml", "--out", "out", "--workers", "2"]
    process = start(args, tmp_path)
    runs = tmp_path / "out" / "runs"
    wait_for_files("*.json", runs, 2, process)
    status, output = interrupt(process, sig, whole_group)
    assert status == code, output[-2000:]
    assert "Traceback" not in output
    finished = sorted(runs.glob("*.json"))
    assert 2 <= len(finished) < 16
    for path in finished:
        record = json.loads(path.read_text())  # whole, valid JSON: written atomically
        assert len(record["metrics"]["Ep"]) == 6
    table = (tmp_path / "out" / "results.csv").read_text().splitlines()
    assert len(table) - 1 >= len(finished) - 2  # the table follows the finished runs (atomic rewrites)
    before = snapshot(finished)

    resume(args, tmp_path)
    after = snapshot(sorted(runs.glob("*.json")))
    assert len(after) == 16
    assert {name: after[name] for name in before} == before
    assert len((tmp_path / "out" / "results.csv").read_text().splitlines()) == 17


def test_an_interrupt_while_writing_keeps_the_runs_that_were_running(tmp_path):
    """The executor's side of an interrupt: Ctrl-C lands while the driver writes the first
    result. That result is written whole, the runs already running finish and are written,
    the rest is cancelled, then the KeyboardInterrupt propagates; the next call reuses all."""
    config = ExperimentConfig(duration=0.5)
    specs = [RunSpec("clean", name, seed, config) for seed in range(5) for name in ("SMC", "MPC")]
    written: list[str] = []

    def on_result(task, result) -> None:
        written.append(task.id)
        if len(written) == 1:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        run_tasks(specs, run_one, TrajectoryFiles(tmp_path), LocalExecutor(workers=2), on_result=on_result)
    files = sorted(tmp_path.glob("*.npz"))
    assert 2 <= len(files) < len(specs)  # the first result and at least the other worker's run
    assert len(set(written)) == len(files) and not list(tmp_path.glob(".*.tmp"))
    finished, todo = TrajectoryFiles(tmp_path).lookup(specs)
    assert sorted(finished) == sorted(f.stem for f in files) and len(todo) == len(specs) - len(files)
    # the pool is shut down and joined before the interrupt propagates: no manager thread or
    # worker left for the interpreter's exit hook, which can race the manager thread closing its
    # wake-up pipe ("OSError: [Errno 9] Bad file descriptor" printed after an interrupted sweep)
    managers = [t for t in threading.enumerate() if type(t).__name__ == "_ExecutorManagerThread" and t.is_alive()]
    assert managers == [] and multiprocessing.active_children() == []
