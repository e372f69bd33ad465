"""The real-water validation campaign of docs/validation-real.md: replay and calibrate the tested
BlueROV2 with the tested Alpha and with hydroarm's built-in Alpha 5 on the Hinsdale 2023 trials.

    python scripts/hinsdale_validation.py PATH/TO/hinsdale-2023/trials --out docs/results/validation-real

For each arm: the uncalibrated replay of every arm-motion trial (timed), then for each split
(training and held-out trials, listed below) a calibration on the training trials (timed) and the
replays of both sets with the calibrated file. Writes ``results.json`` (every number of the page)
and the figures of a few held-out trials. Nothing here is hard-coded into hydroarm: the splits are
this campaign's arguments to ``calibrate``.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from hydroarm.studies.calibrate import calibrate, replay_config, write_calibrated_vehicle
from hydroarm.studies.replay import ReplayConfig, build_system, load_vehicle_quietly, replay_many, summary, write_trial

ROOT = Path(__file__).resolve().parents[1]
VEHICLES = {
    "tested_alpha": ROOT / "examples" / "hinsdale" / "bluerov2_hinsdale.toml",
    "builtin_alpha5": ROOT / "examples" / "hinsdale" / "bluerov2_hinsdale_alpha5.toml",
}
EXTENDED = ["cb_x", "cb_y", "cb_z", "rotational_linear_damping_scale", "arm_buoyancy_scale", "imu_yaw_deg",
            "joint_time_offset", "trim"]  # fmt: skip
PARAMETERS = {  # arm: {parameter set: the parameters calibrated}
    "tested_alpha": {"base": ["cb_x", "cb_y", "cb_z", "rotational_damping_scale"], "extended": EXTENDED},
    "builtin_alpha5": {
        "base": ["cb_x", "cb_y", "cb_z", "arm_buoyancy_scale", "rotational_damping_scale"],
        "extended": EXTENDED,
    },
}
ALT = [f"traj_alt_{c}" for c in ("001-0", "001-1", "001-2", "002-0", "002-1", "008-0", "008-1", "008-2",
                                 "009-0", "009-1", "011-0", "011-1", "011-2")]  # fmt: skip
SPLITS = {
    "A: 6 alt / 7 alt": (
        ["traj_alt_001-0", "traj_alt_001-1", "traj_alt_002-0", "traj_alt_008-0", "traj_alt_009-1", "traj_alt_011-0"],
        None,
    ),
    "B: 6 alt / 7 alt (other pick)": (
        ["traj_alt_001-2", "traj_alt_002-1", "traj_alt_008-1", "traj_alt_008-2", "traj_alt_009-0", "traj_alt_011-1"],
        None,
    ),
    "C: family, 6 traj0NN / 13 alt": (
        ["traj004-0", "traj006-0", "traj012-0", "traj015-0", "traj020-0", "traj026-0"],
        ALT,
    ),
    "D: family, 6 alt / 44 traj0NN": (
        ["traj_alt_001-0", "traj_alt_001-1", "traj_alt_002-0", "traj_alt_008-0", "traj_alt_009-1", "traj_alt_011-0"],
        "traj0",
    ),
}
KEYS = ("pitch_rmse_imu_deg", "roll_rmse_imu_deg", "pitch_rmse_mocap_deg", "roll_rmse_mocap_deg",
        "pitch_rmse_hold_deg", "roll_rmse_hold_deg", "pitch_imu_vs_mocap_deg", "roll_imu_vs_mocap_deg",
        "pitch_peak_abs_error_imu_deg", "roll_peak_abs_error_imu_deg")  # fmt: skip


def _mean(results, names):
    table = summary([r for r in results if r.name in names])
    return {k: table["mean"].get(k) for k in KEYS} | {"n_trials": table["n_trials"]}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("trials", type=Path, nargs="?")
    parser.add_argument("--out", type=Path)
    parser.add_argument("--tables", type=Path, help="print the page's tables from this results.json and stop")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--arms", nargs="+", default=list(VEHICLES), choices=list(VEHICLES))
    parser.add_argument("--params", default=None, help="comma-separated parameters for every arm: one set, 'custom'")
    parser.add_argument("--sets", default="base,extended", help="which parameter sets of PARAMETERS (comma-separated)")
    parser.add_argument("--splits", default="ABCD", help="which splits (letters), default all")
    args = parser.parse_args()
    if args.tables:
        print(tables(json.loads(args.tables.read_text())))
        return
    if args.trials is None or args.out is None:
        parser.error("give the trials folder and --out (or --tables results.json)")
    sets = args.sets.split(",")
    if args.params:
        for arm in VEHICLES:
            PARAMETERS[arm] = {"custom": args.params.split(",")}
        sets = ["custom"]
    args.out.mkdir(parents=True, exist_ok=True)
    config = ReplayConfig()
    every = sorted(p for p in args.trials.glob("traj*_joint_states.csv") if "-test" not in p.name)
    by_name = {p.name.removesuffix("_joint_states.csv"): p for p in every}
    out: dict = {"n_trials": len(every), "settings": config.model_dump(), "arms": {}}
    for arm, vehicle_path in VEHICLES.items():
        if arm not in args.arms:
            continue
        spec = load_vehicle_quietly(vehicle_path)
        began = time.perf_counter()
        base = replay_many(every, spec, "mount", config, workers=args.workers)
        seconds = time.perf_counter() - began
        record: dict = {
            "replay_all_seconds": seconds,
            "uncalibrated_all": _mean(base, set(by_name)),
            "uncalibrated_alt": _mean(base, set(ALT)),
            "calibrations": {},
        }
        print(f"{arm}: {len(every)} trials replayed in {seconds:.1f} s", flush=True)
        for name in sets:
            names = PARAMETERS[arm][name]
            calibration: dict = {"parameters": names, "splits": {}}
            record["calibrations"][name] = calibration
            for split, (train, held) in SPLITS.items():
                if split[0] not in args.splits:
                    continue
                if held is None:
                    held = [n for n in ALT if n not in train]
                elif isinstance(held, str):
                    held = [n for n in by_name if n.startswith(held)]
                fit = calibrate([by_name[n] for n in train], spec, "mount", names, config, workers=args.workers)
                slug = split.split(":")[0]
                calibrated_path = args.out / f"{arm}_{name}_{slug}.toml"
                write_calibrated_vehicle(calibrated_path, spec, fit, train, build_system(spec).arm, config)
                calibrated = load_vehicle_quietly(calibrated_path)
                fitted = replay_config(config, fit.values)  # the fitted replay settings (joint_time_offset, ...)
                replays = replay_many([by_name[n] for n in train + held], calibrated, "mount", fitted, args.workers)
                calibration["splits"][split] = {
                    "train": train,
                    "held_out": held,
                    "parameters": {n: [fit.values[n], fit.uncertainty[n]] for n in fit.names},
                    "correlation": fit.correlation,
                    "cost_deg2": [fit.initial_cost, fit.cost],
                    "calibrate_seconds": fit.seconds,
                    "evaluations": fit.evaluations,
                    "uncalibrated_train": _mean(base, set(train)),
                    "uncalibrated_held_out": _mean(base, set(held)),
                    "calibrated_train": _mean(replays, set(train)),
                    "calibrated_held_out": _mean(replays, set(held)),
                    "calibrated_held_out_trials": {
                        r.name: {k: r.metrics[k] for k in KEYS[:2] + KEYS[6:8]} for r in replays if r.name in held
                    },
                }
                if slug == "A" and arm == "tested_alpha" and name == sets[-1]:
                    for result in replays:
                        if result.name in ("traj_alt_002-1", "traj_alt_009-0", "traj_alt_011-1"):
                            write_trial(args.out / "figures", result)
                held_out = calibration["splits"][split]["calibrated_held_out"]
                print(
                    f"{arm} {name} {split}: held-out pitch {held_out['pitch_rmse_imu_deg']:.2f} roll "
                    f"{held_out['roll_rmse_imu_deg']:.2f} deg; fit {fit.seconds:.0f} s",
                    flush=True,
                )
        out["arms"][arm] = record
        (args.out / "results.json").write_text(json.dumps(out, indent=1, default=float) + "\n")


def _pair(row: dict, key: str = "rmse_imu_deg") -> str:
    return f"{row['pitch_' + key]:.2f} / {row['roll_' + key]:.2f}"


def tables(results: dict) -> str:
    """The page's tables (Markdown) from a results.json: pitch / roll RMSE vs the IMU, degrees."""
    arms = results["arms"]
    tested, alpha5 = arms["tested_alpha"], arms["builtin_alpha5"]
    lines = ["| trials | hold | hydroarm, tested Alpha | hydroarm, built-in Alpha 5 |", "|---|---|---|---|"]
    for label, key in (("13 `_alt_`", "uncalibrated_alt"), ("all 57", "uncalibrated_all")):
        hold = _pair(tested[key], "rmse_hold_deg")
        lines.append(f"| {label} | {hold} | {_pair(tested[key])} | {_pair(alpha5[key])} |")
    out = ["\n".join(lines)]
    for name in tested["calibrations"]:
        rows = [
            f"Parameter set `{name}`: tested Alpha {', '.join(tested['calibrations'][name]['parameters'])}; "
            f"built-in Alpha 5 {', '.join(alpha5['calibrations'][name]['parameters'])}.",
            "",
            "| split (train / held-out) | hold | tested Alpha uncal. | tested Alpha calibrated: train, **held-out** "
            "| built-in Alpha 5 calibrated: train, **held-out** | floor (IMU-mocap) | fit s (tested, Alpha 5) |",
            "|---|---|---|---|---|---|---|",
        ]
        for split, row in tested["calibrations"][name]["splits"].items():
            other = alpha5["calibrations"][name]["splits"][split]
            rows.append(
                f"| {split} | {_pair(row['uncalibrated_held_out'], 'rmse_hold_deg')} "
                f"| {_pair(row['uncalibrated_held_out'])} "
                f"| {_pair(row['calibrated_train'])}, **{_pair(row['calibrated_held_out'])}** "
                f"| {_pair(other['calibrated_train'])}, **{_pair(other['calibrated_held_out'])}** "
                f"| {_pair(row['calibrated_held_out'], 'imu_vs_mocap_deg')} "
                f"| {row['calibrate_seconds']:.0f}, {other['calibrate_seconds']:.0f} |"
            )
        out.append("\n".join(rows))
    return "\n\n".join(out)


if __name__ == "__main__":
    main()
