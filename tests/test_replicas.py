"""The reproduction's replicated rows (issue 29): the plan, the perturbed starts, the printed digits,
and scripts/reproducibility.py's verdicts."""

from __future__ import annotations

import importlib.util
import math
from pathlib import Path

import numpy as np
import pytest

from hydroarm.config import ConfigError
from hydroarm.model.arm.loading import load_arm
from hydroarm.sim.experiment import ExperimentConfig, start_for_arm
from hydroarm.studies.reproduce import plan_runs, plan_study, replica_config
from hydroarm.studies.reproduce_numbers import held, held_digits
from hydroarm.studies.reproduce_rows import REPLICA_OFFSET, REPLICATED_ROWS

ROOT = Path(__file__).resolve().parents[1]


def _script():
    spec = importlib.util.spec_from_file_location("reproducibility", ROOT / "scripts" / "reproducibility.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_plan_repeats_the_clean_gp_rows_from_perturbed_starts():
    base = ExperimentConfig(duration=1.0)
    plain = plan_runs(base, 2, ablation=False)
    replicated = plan_runs(base, 2, ablation=False, replicas=4)
    extra = [spec for spec in replicated if spec.case.startswith("replica")]
    assert len(replicated) == len(plain) + 3 * len(REPLICATED_ROWS) == len(plain) + len(extra)
    assert {spec.controller for spec in extra} == set(REPLICATED_ROWS)
    assert len({spec.key for spec in replicated}) == len(replicated)
    clean = {spec.controller: spec for spec in plain if spec.case == "clean"}
    for spec in extra:  # the row's own settings, only the start moved
        assert spec.config.initial_state.position_spread == REPLICA_OFFSET
        assert spec.config.model_copy(update={"initial_state": clean[spec.controller].config.initial_state}) == (
            clean[spec.controller].config
        )
        assert spec.build == clean[spec.controller].build


def test_a_replica_starts_within_the_offset_of_the_task_start():
    arm = load_arm("paper")
    base = ExperimentConfig(duration=1.0)
    _, x0 = start_for_arm(arm, base)
    starts = [start_for_arm(arm, replica_config(base, r))[1] for r in range(4)]
    np.testing.assert_array_equal(starts[0], x0)  # replica 0 is the row itself
    for start in starts[1:]:
        moved = start - x0
        assert np.all(np.abs(moved[:6]) <= REPLICA_OFFSET) and np.any(moved[:6] != 0) and np.all(moved[6:] == 0)
    assert not np.array_equal(starts[1], starts[2])


def test_replicas_is_refused_out_of_range():
    with pytest.raises(ConfigError, match="replicas"):
        plan_study(quick=True, replicas=0)
    assert plan_study(quick=True).replicas == 4 and plan_study(quick=True, replicas=1).replicas == 1


@pytest.mark.parametrize(
    ("x", "spread", "text"),
    [
        (0.0504, 0.0213, "0.05 ± 0.03"),
        (12.34, 3.1, "12 ± 4"),
        (0.0874, 0.0009, "0.0874 ± 0.0009"),
        (0.1, 1e-12, "0.1"),  # every printed digit holds
        (0.2, None, "0.2"),
    ],
)
def test_only_the_digits_the_spread_leaves_are_printed(x, spread, text):
    assert held_digits(x, spread) == text


def test_held_reads_the_replicas_of_a_clean_row_and_the_seeds_of_a_noisy_one():
    clean = {"Ep": [1.0, 2.0], "replicas": {"Ep_mean": [1.5, 2.5], "Ep_spread": [0.1, 0.2],
                                            "Ep_mean_of_joints_spread": 0.05}}  # fmt: skip
    assert held(clean) == ([1.5, 2.5], [0.1, 0.2], 2.0, 0.05)
    noisy = {"Ep": [1.0, 3.0], "Ep_spread": [0.3, 0.1], "Ep_mean_of_joints_spread": 0.2}
    assert held(noisy) == ([1.0, 3.0], [0.3, 0.1], 2.0, 0.2)
    assert held({"Ep": [1.0, 3.0]}) == ([1.0, 3.0], None, 2.0, None)


def test_reproducibility_judges_plain_rows_to_1e9_and_replicated_rows_by_their_runs():
    script = _script()

    def summary(plain: float, runs: list[list[float]]) -> dict:
        mean = np.mean(runs, axis=0).tolist()
        return {"clean": {
            "MPC": {"Ep": [plain, 1.0]},
            "GP-MPC": {"Ep": runs[0], "replicas": {"Ep_per_replica": runs, "Ep_mean": mean}},
        }}  # fmt: skip

    runs = [[1.0, 2.0], [1.2, 2.1], [0.9, 1.8]]
    reference = summary(1.0, runs)
    assert all(row["holds"] for row in script.compare(reference, summary(1.0 + 1e-12, runs)).values())
    rows = script.compare(reference, summary(1.0 + 1e-8, [[1.1, 2.0], [1.0, 1.9], [1.05, 2.05]]))
    assert not rows["clean/MPC"]["holds"] and rows["clean/GP-MPC"]["holds"]
    assert math.isclose(rows["clean/GP-MPC"]["max_ranges"], abs(1.05 - 31 / 30) / (0.3 + 0.1))
    rows = script.compare(reference, summary(1.0, [[2.0, 2.0], [2.1, 2.0], [2.2, 2.0]]))  # moved beyond its runs
    assert not rows["clean/GP-MPC"]["holds"]


def test_reproducibility_splits_the_ablations_by_controller_and_marks_their_gp_runs():
    """An ablation's MPC numbers are judged to 1e-9; its GP runs (single, not replicated) are marked
    chaotic when they differ, which --check reports without failing on; its gains are derived."""
    script = _script()

    def summary(mpc: float, gp: float, idmpc: float) -> dict:
        return {
            "ablation": {"R": {"0.1": {"MPC": {"Ep": [mpc, 1.0]}, "GP-MPC": {"Ep": [gp, 1.0]},
                                       "gain_mean_of_joints": 100.0 * (1.0 - gp / mpc)}}},
            "ablation_idmpc": {"GP": {"off": {"controller": "IDMPC+KF", "Ep": [idmpc]},
                                      "on": {"controller": "GP-IDMPC+KF", "Ep": [gp]}}},
        }  # fmt: skip

    reference = summary(1.0, 0.5, 2.0)
    rows = script.compare(reference, summary(1.0, 0.6, 2.0))
    assert set(rows) == {"ablation/R/MPC", "ablation/R/GP-MPC", "ablation/R/gain",
                         "ablation_idmpc/GP/IDMPC+KF", "ablation_idmpc/GP/GP-IDMPC+KF"}  # fmt: skip
    assert rows["ablation/R/MPC"]["holds"] and rows["ablation_idmpc/GP/IDMPC+KF"]["holds"]
    assert rows["ablation/R/GP-MPC"]["chaotic"] and not rows["ablation/R/GP-MPC"]["holds"]
    assert rows["ablation_idmpc/GP/GP-IDMPC+KF"]["chaotic"] and rows["ablation/R/gain"]["derived"]
    rows = script.compare(reference, summary(1.0 + 1e-8, 0.5, 2.0 + 1e-8))  # a plain run moved: fails
    assert not rows["ablation/R/MPC"]["holds"] and not rows["ablation/R/MPC"].get("chaotic")
    assert not rows["ablation_idmpc/GP/IDMPC+KF"]["holds"] and rows["ablation/R/GP-MPC"]["holds"]


def test_the_ablations_repeat_every_gp_run_from_perturbed_starts():
    """Every GP run of the two ablations gets replicas 1..K-1 (its own settings, only the start
    moved); their MPC / IDMPC runs do not, and replica 0 keeps the unreplicated plan's key."""
    base = ExperimentConfig(duration=1.0)
    plain = [s for s in plan_runs(base, 1, ablation=True) if s.case.startswith("ablation")]
    replicated = [s for s in plan_runs(base, 1, ablation=True, replicas=8) if s.case.startswith("ablation")]
    gp_plain = [s for s in plain if s.controller.startswith("GP-")]
    extra = [s for s in replicated if "-replica" in s.case.split("/")[0]]
    assert len(extra) == 3 * len(gp_plain) and {s.key for s in plain} <= {s.key for s in replicated}
    assert all(s.controller.startswith("GP-") for s in extra)
    assert all(s.config.initial_state.position_spread == REPLICA_OFFSET for s in extra)


def test_an_ablation_cell_with_replicas_prints_their_mean_and_spread(tmp_path):
    """summarise / write_tables on real (short) runs: the GP cell's E_p is its replicas' mean with
    the digits their spread leaves, its gain taken from that mean."""
    from hydroarm.sim.experiment import run_experiment
    from hydroarm.studies.reproduce_numbers import ablation_held, ablation_metrics

    base = ExperimentConfig(duration=0.3, gp={"window": 5})
    specs = [s for s in plan_runs(base, 1, ablation=True, replicas=3) if s.case.startswith(("ablation/R=",
             "ablation-replica1/R=", "ablation-replica2/R="))]  # fmt: skip
    results = {s.key: run_experiment(s.config, s.build or s.controller, s.seed) for s in specs}
    ablation, _ = ablation_metrics(specs, results)
    for row in ablation["R"].values():
        cell = row["GP-MPC"]
        assert cell["replicas"]["count"] == 3 and "replicas" not in row["MPC"]
        per_joint, mean, spread, _, _ = ablation_held(cell)
        runs = np.array(cell["replicas"]["Ep_per_replica"])
        np.testing.assert_allclose(per_joint, runs.mean(axis=0), rtol=1e-15)
        assert mean == pytest.approx(runs.mean()) and spread == pytest.approx(runs.mean(axis=1).std(ddof=1))
        gains = 100.0 * (1.0 - runs.mean(axis=0) / np.array(row["MPC"]["Ep"]))
        assert row["gain_mean_of_joints"] == pytest.approx(gains.mean())


def test_reproducibility_judges_a_replicated_ablation_cell_within_its_runs():
    script = _script()

    def summary(gp_runs: list[list[float]]) -> dict:
        mean = np.mean(gp_runs, axis=0).tolist()
        cell = {"Ep": gp_runs[0], "replicas": {"Ep_per_replica": gp_runs, "Ep_mean": mean}}
        return {"ablation": {"R": {"0.1": {"MPC": {"Ep": [1.0, 1.0]}, "GP-MPC": cell}}}}

    reference = summary([[1.0, 2.0], [1.2, 2.1], [0.9, 1.8]])
    rows = script.compare(reference, summary([[1.1, 2.0], [1.0, 1.9], [1.05, 2.05]]))
    assert rows["ablation/R/GP-MPC"]["holds"] and not rows["ablation/R/GP-MPC"].get("chaotic")
    rows = script.compare(reference, summary([[2.0, 2.0], [2.1, 2.0], [2.2, 2.0]]))
    assert not rows["ablation/R/GP-MPC"]["holds"]
