"""The measured figures the docs state are the ones in docs/data/measured.json (issue 24), which
scripts/docs_figures.py writes from results files (summary.json of a full and a quick
reproduction, the example sweep's wall time), with the machine, its load and the date; the speed
figures the docs take from `hydroarm bench` are bench/results/bench.json's, and those of a study
its docs/data file's."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
MEASURED = json.loads((ROOT / "docs" / "data" / "measured.json").read_text())
BENCH = json.loads((ROOT / "bench" / "results" / "bench.json").read_text())


def _text(path: str) -> str:
    return " ".join((ROOT / path).read_text().split())  # line breaks as spaces


def test_the_measurement_says_on_what_and_when():
    assert MEASURED["date"] and MEASURED["load_average"] and MEASURED["machine"]["cpus"] >= 1


def test_the_readmes_install_time_is_the_measured_one():
    """The README's time with the install is in measured.json's note on the run, not a key."""
    assert "376 s with the install" in MEASURED["load_average"]
    assert "376 s with the install" in _text("README.md")


@pytest.mark.parametrize(
    ("path", "phrase"),
    [
        ("README.md", "{reproduce_seconds} s on a {cpus}-core machine"),
        ("docs/index.md", "{reproduce_seconds} s on a {cpus}-core machine"),
        ("docs/tutorial.md", "({reproduce_seconds} s on a quiet {cpus}-core machine"),
        ("docs/tutorial.md", "in {reproduce_quick_seconds} s"),
        ("docs/tutorial.md", "the ablation ({reproduce_seconds} s"),
        ("docs/tutorial.md", "24 runs, {sweep_example_seconds} s"),
        ("examples/sweep.toml", "24 runs of 4 s ({sweep_example_seconds} s"),
        ("docs/deviations.md", "{gain_torque_percent} % vs {gain_acceleration_percent} %"),
        ("docs/deviations.md", "cost {cost5}x and {cost20}x"),
        ("docs/deviations.md", "{gain5} % and {gain20} % against {gain1} %"),
    ],
)
def test_a_typed_figure_is_the_measured_one(path, phrase):
    values = {
        **MEASURED,
        "cpus": MEASURED["machine"]["cpus"],
        "cost5": MEASURED["hyperparameter_steps_cost_ratio"]["5"],
        "cost20": MEASURED["hyperparameter_steps_cost_ratio"]["20"],
        **{f"gain{k}": v for k, v in MEASURED["hyperparameter_steps_gain_percent"].items()},
    }
    assert phrase.format(**values) in _text(path), f"{path}: {phrase.format(**values)!r}"


@pytest.mark.parametrize(
    ("path", "stale"),
    [
        ("README.md", "about two minutes"),
        ("docs/index.md", "about two minutes"),
        ("docs/vehicle.md", "0.79 ms median"),
        ("docs/vehicle.md", "269x"),
        ("docs/vehicle.md", "0.165 ms"),
        ("docs/model.md", "about 20 us"),
        ("docs/controllers.md", "about 60 us"),
        ("docs/controllers.md", "0.11 against 0.29 ms"),
        ("docs/validation-real.md", "replayed in 6.6 s"),
        ("docs/validation.md", "about 10 s"),
        ("docs/robustness.md", "7-12 min"),
        ("bench/README.md", "~8 minutes"),
        ("docs/tutorial.md", "about 20 s"),
        ("docs/tutorial.md", "about two minutes"),
        ("docs/tutorial.md", "about 15 s"),
        ("examples/sweep.toml", "about 15 s"),
        ("docs/deviations.md", "about 32 %"),
        ("docs/deviations.md", "2-5x"),
    ],
)
def test_no_unmeasured_figure_is_left(path, stale):
    assert stale not in _text(path)


def _at(data, key: str):
    """data["a"]["b"][0] for "a.b.0"."""
    for part in key.split("."):
        data = data[int(part)] if isinstance(data, list) else data[part]
    return data


US = 1e3  # ms -> us
MB = 1e-6  # bytes -> MB


@pytest.mark.parametrize(
    ("path", "phrase", "source", "keys"),
    [
        # (page, the phrase with {0}, {1}, ... formatted as the page rounds them, results file, its keys:
        # "a.b.c" or ("a.b.c", factor))
        (
            "docs/vehicle.md",
            "one core: {0:.2f} ms median, i.e. {1:.1f}x faster than real time",
            "bench/results/bench.json",
            ["uvms.reference.median_step_ms", "uvms.reference.real_time_factor"],
        ),
        (
            "docs/vehicle.md",
            "the fixed-base paper arm: {0:.2f} ms",
            "bench/results/bench.json",
            ["peers.plant.plant_step_ms.median"],
        ),
        (
            "docs/vehicle.md",
            "reference {0:.2f} ms ({1:.1f}x real time)",
            "bench/results/bench.json",
            ["uvms.reference.median_step_ms", "uvms.reference.real_time_factor"],
        ),
        (
            "docs/vehicle.md",
            "compiled, default settings {0:.3f} ms = **{1:.0f}x real time**",
            "bench/results/bench.json",
            ["uvms.median_step_ms", "uvms.real_time_factor"],
        ),
        (
            "docs/model.md",
            "evaluation of water + dynamics + solve costs {0:.0f} us on the paper arm",
            "bench/results/bench.json",
            [("peers.plant.evaluation_water_plus_rigid_body_ms.median", US)],
        ),
        (
            "docs/controllers.md",
            "doubling algorithm ({0:.0f} us median per MPC step in `hydroarm bench`",
            "bench/results/bench.json",
            [("breakdown.MPC.riccati.median", US)],
        ),
        (
            "docs/controllers.md",
            "gives PI-IDMPC median {0:.3f} ms, p99 {1:.1f} ms",
            "bench/results/bench.json",
            ["pi_idmpc_step_ms.median", "pi_idmpc_step_ms.p99"],
        ),
        (
            "docs/controllers.md",
            "(median {0:.2f} ms per step, GP and filter included",
            "bench/results/bench.json",
            ["gp_idmpc_step_ms.median"],
        ),
        (
            "docs/controllers.md",
            "median {0:.3f} ms, p99 {1:.3f} ms, max {2:.2f} ms on the paper task, {3:.3f} / {4:.3f} / {5:.2f} ms "
            "with the UR5's limits, {6:.3f} / {7:.3f} / {8:.2f} ms in the issue's real loop",
            "bench/results/bench-flagship.json",
            [
                f"flagship.cases.{case}.GP-IDMPC.step.{key}"
                for case in ("paper", "paper, UR5 limits", "paper, the issue's real loop")
                for key in ("median", "p99", "max")
            ],
        ),
        (
            "docs/controllers.md",
            "{0:.1f}x, {1:.1f}x and {2:.1f}x IDMPC's in the same runs: **within",
            "bench/results/bench-flagship.json",
            [
                f"flagship.cases.{case}.median_ratio"
                for case in ("paper", "paper, UR5 limits", "paper, the issue's real loop")
            ],
        ),
        (
            "docs/validation-real.md",
            "load average {0:.1f}, 2026-12-02): all {1} trials ({2:.0f} s of logs) replayed in {3:.1f} s",
            "bench/results/bench.json",
            ["replay.full.load_average.0", "replay.full.trials", "replay.full.simulated_s", "replay.full.replay_all_s"],
        ),
        (
            "docs/validation-real.md",
            "on 6 trials in {0:.1f} s, {1} replays",
            "bench/results/bench.json",
            ["replay.full.calibrate_s", "replay.full.calibrate_replays"],
        ),
        (
            "docs/validation-real.md",
            "replayed in {0:.1f} s (tested Alpha) and {1:.1f} s (Alpha 5)",
            "docs/data/validation-real/results.json",
            ["arms.tested_alpha.replay_all_seconds", "arms.builtin_alpha5.replay_all_seconds"],
        ),
        (
            "docs/viewer.md",
            "to the arm drawn in headless Chromium | {0:.2f} s |",
            "bench/results/bench.json",
            ["viewer.open_to_drawn_s.median"],
        ),
        (
            "docs/viewer.md",
            "the server listening | {0:.2f} s |",
            "bench/results/bench.json",
            ["viewer.open_to_listening_s.median"],
        ),
        (
            "docs/viewer.md",
            "`hydroarm view --out run.html` (written) | {0:.2f} s |",
            "bench/results/bench.json",
            ["viewer.write_html_s.median"],
        ),
        (
            "docs/viewer.md",
            "size of `run.html` | {0:.1f} MB",
            "bench/results/bench.json",
            [("viewer.html_bytes", MB)],
        ),
        (
            "bench/README.md",
            "the full suite took {0:.0f} s for `bench/results/bench.json`",
            "bench/results/bench.json",
            ["suite_wall_s"],
        ),
        (
            "docs/robustness.md",
            "{0:.0f} s wall on 2 workers ({1:.0f} s of run time",
            "docs/data/real_loop.json",
            ["wall_time_s", "cpu_time_s"],
        ),
    ],
)
def test_a_typed_speed_is_its_results_file(path, phrase, source, keys):
    data = json.loads((ROOT / source).read_text())
    values = [_at(data, key) if isinstance(key, str) else _at(data, key[0]) * key[1] for key in keys]
    assert phrase.format(*values) in _text(path), f"{path}: {phrase.format(*values)!r} ({source})"


def test_the_uvms_path_at_the_reference_settings_is_bench_json_once_it_has_it():
    """bench/hydroarm_bench/uvms.py writes uvms.compiled_fine (1 ms, 8 drag points) since
    2026-12-03; until bench.json is regenerated docs/vehicle.md states a dated measurement."""
    fine = BENCH["uvms"].get("compiled_fine")
    if fine is None:
        assert "0.17-0.21 ms (47-58x) in two runs on 2026-12-03" in _text("docs/vehicle.md")
        return
    phrase = f"Same physics at 1 ms / 8 points: {fine['median_step_ms']:.3f} ms ({fine['real_time_factor']:.0f}x)"
    assert phrase in _text("docs/vehicle.md"), phrase


def test_the_gated_tde_step_is_the_learning_studys():
    """docs/controllers.md: IDMPC with the gated TDE against GP-IDMPC, the median of the learning
    study's paper-task runs' median steps."""
    study = json.loads((ROOT / "docs" / "data" / "learning_study.json").read_text())["paper"]

    def median_step(controller: str) -> float:
        runs = [run for case in study[controller].values() for run in case]
        return float(np.median([run["step_ms_median"] for run in runs]))

    phrase = f"({median_step('IDMPC+TDE-gated'):.3f} against {median_step('GP-IDMPC'):.3f} ms, the median"
    assert phrase in _text("docs/controllers.md"), phrase


def test_the_campaigns_fit_times_are_its_results():
    """docs/validation-real.md: the range of the campaign's calibration times, per parameter set."""
    results = json.loads((ROOT / "docs" / "data" / "validation-real" / "results.json").read_text())
    text = _text("docs/validation-real.md")
    for name, phrase in (("base", "the `base` fits took {}-{} s"), ("extended", "`extended` fits {}-{} s")):
        seconds = [
            split["calibrate_seconds"]
            for arm in results["arms"].values()
            for split in arm["calibrations"][name]["splits"].values()
        ]
        assert phrase.format(round(min(seconds)), round(max(seconds))) in text, name


def test_no_page_cites_files_users_do_not_have():
    for path in [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md")), *sorted((ROOT / "src").rglob("*.py"))]:
        assert "../shared" not in path.read_text(), path


def test_the_start_up_learning_table_is_the_learning_studys():
    """docs/controllers.md, "Learning the start-up": every cell of its table (whole-run mean E_p,
    clean / noisy) is docs/data/learning_study.json's, the best observer's column included."""
    study = json.loads((ROOT / "docs" / "data" / "learning_study.json").read_text())
    text = _text("docs/controllers.md")
    observers = ("IDMPC+TDE", "IDMPC+TDE-gated", "IDMPC+NDOB", "IDMPC+NDOB-gated")
    columns = ("PI-IDMPC", "PI-IDMPC, start-up learned", "PI-IDMPC, start-up learned, gated remainder")

    def cell(runs_by_table) -> str:
        return " / ".join(
            f"{np.mean([run['Ep_mean'] for run in runs_by_table[table]]):.5g}" for table in ("clean", "noisy")
        )

    for case, rows in study.items():
        best = " / ".join(
            f"{min(np.mean([run['Ep_mean'] for run in rows[o][table]]) for o in observers):.5g}"
            for table in ("clean", "noisy")
        )
        line = "| " + " | ".join([case, best, *(cell(rows[column]) for column in columns)]) + " |"
        assert line in text.replace("**", ""), line


LEARNING_OBSERVERS = ("IDMPC+TDE", "IDMPC+TDE-gated", "IDMPC+NDOB", "IDMPC+NDOB-gated")
"""The learning study's observer rows (scripts/learning_study.py)."""


def _study_mean(runs, key="Ep_mean"):
    """The mean of ``key`` over a learning-study cell's runs."""
    return float(np.mean([run[key] for run in runs]))


def _pair(values, digits=5):
    """Clean / noisy as the docs print them."""
    return " / ".join(f"{v:.{digits}g}".replace("e-0", "e-") for v in values)


def test_the_learning_table_is_the_learning_studys():
    """docs/controllers.md, "Learning against the classic observers": every number of its table
    (the best observer by clean whole-run E_p, GP-IDMPC, PI-IDMPC, PI-IDMPC and the best observer
    after 2 s, clean / noisy) is docs/data/learning_study.json's, to the digits printed."""
    study = json.loads((ROOT / "docs" / "data" / "learning_study.json").read_text())
    text = _text("docs/controllers.md").replace("**", "")
    observers = dict(zip(LEARNING_OBSERVERS, ("TDE", "TDE-gated", "NDOB", "NDOB-gated"), strict=True))
    mean, pair = _study_mean, _pair

    for case, rows in study.items():
        tables = ("clean", "noisy")
        best = min(observers, key=lambda row: mean(rows[row]["clean"]))
        after = [min(mean(rows[o][t], "Ep_mean_after_2s") for o in observers) for t in tables]
        cells = [
            case,
            f"{observers[best]} {pair([mean(rows[best][t]) for t in tables])}",
            pair([mean(rows["GP-IDMPC"][t]) for t in tables]),
            pair([mean(rows["PI-IDMPC"][t]) for t in tables]),
            pair([mean(rows["PI-IDMPC"][t], "Ep_mean_after_2s") for t in tables], 3),
            pair(after, 3),
        ]
        line = "| " + " | ".join(cells) + " |"
        assert line in text, line


def test_the_transfer_limit_is_the_transfer_studys():
    """docs/controllers.md: the plant's own coefficients against the prior over the first 2 s."""
    rows = json.loads((ROOT / "docs" / "data" / "transfer_study.json").read_text())["clean"]["rows"]
    own = rows["PI-IDMPC, the plant's own coefficients"]["Ep_mean_first_2s"]
    prior = rows["PI-IDMPC, textbook prior"]["Ep_mean_first_2s"]
    phrase = f"PI-IDMPC's first 2 s are {own:.1e}, {prior / own:.1f}x below the prior's {prior:.1e}"
    assert phrase in _text("docs/controllers.md"), phrase


def test_the_identification_figures_are_the_identification_studys():
    """docs/controllers.md, "Identification from a log": the largest errors over the noisy seeds
    (instrumental variables, and least squares in brackets) are docs/data/water_identification.json's."""
    runs = json.loads((ROOT / "docs" / "data" / "water_identification.json").read_text())["runs"]

    def largest(method: str, key: str, cylinders: list[int]) -> float:
        chosen = [r for name, r in runs.items() if name.startswith("noisy") and name.endswith(method)]
        return 100 * max(abs(r["relative_error"][key][c - 1]) for r in chosen for c in cylinders)

    iv, ls = "instrumental variables", "least squares"
    text = _text("docs/controllers.md")
    phrases = [
        f"C_m of cylinders 2, 3, 5, 6 within {largest(iv, 'cm', [2, 3, 5, 6]):.1f} %",
        f"volumes of cylinders 5-6 within {largest(iv, 'volume', [5, 6]):.1f} %",
        f"(least squares without the instruments: {largest(ls, 'cm', [2, 3, 5, 6]):.1f} % and "
        f"{largest(ls, 'volume', [5, 6]):.1f} %)",
        f"cylinders 3, 5, 6 within {largest(iv, 'cd', [3, 5, 6]):.1f} %",
        f"reach {largest(iv, 'cd', [2]):.2f} % and {largest(iv, 'cd', [4]):.1f} % in one seed",
        f"(least squares: {largest(ls, 'cd', [2]):.1f} % and {largest(ls, 'cd', [4]):.1f} %)",
    ]
    for phrase in phrases:
        assert phrase in text, phrase


def test_the_gp_target_table_is_the_learning_studys():
    """docs/controllers.md, "The GP's target": every cell (GP-IDMPC with either target and the best
    observer, column by column, whole run and after 2 s, clean / noisy) is
    docs/data/learning_study.json's, to the digits printed."""
    study = json.loads((ROOT / "docs" / "data" / "learning_study.json").read_text())
    text = _text("docs/controllers.md").replace("**", "")

    def best(rows, names, digits, key):
        return _pair([min(_study_mean(rows[name][t], key) for name in names) for t in ("clean", "noisy")], digits)

    for case, rows in study.items():
        line = [case]
        for names in (("GP-IDMPC",), ("GP-IDMPC, Euler target",), LEARNING_OBSERVERS):
            line += [best(rows, names, 5, "Ep_mean"), best(rows, names, 3, "Ep_mean_after_2s")]
        assert "| " + " | ".join(line) + " |" in text, line
