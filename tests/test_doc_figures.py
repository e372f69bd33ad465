"""The measured figures the docs state are the ones in docs/data/measured.json (issue 24), which
scripts/docs_figures.py writes from results files (summary.json of a full and a quick
reproduction, the example sweep's wall time), with the machine, its load and the date."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
MEASURED = json.loads((ROOT / "docs" / "data" / "measured.json").read_text())


def _text(path: str) -> str:
    return " ".join((ROOT / path).read_text().split())  # line breaks as spaces


def test_the_measurement_says_on_what_and_when():
    assert MEASURED["date"] and MEASURED["load_average"] and MEASURED["machine"]["cpus"] >= 1


@pytest.mark.parametrize(
    ("path", "phrase"),
    [
        ("README.md", "{reproduce_seconds} s on a {cpus}-core machine"),
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


def test_no_page_cites_files_users_do_not_have():
    for path in [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md")), *sorted((ROOT / "src").rglob("*.py"))]:
        assert "../shared" not in path.read_text(), path
