"""Does a controller's run depend on the BLAS kernel or numba's CPU target? Run it (default: the
flagship candidate PI-IDMPC, 10 s of the paper task, clean) in fresh processes under
``OPENBLAS_CORETYPE=Haswell``, under ``OPENBLAS_CORETYPE=Sandybridge NUMBA_CPU_NAME=generic``
(no FMA, no AVX2 in either library) and, on a CPU with AVX-512, ``OPENBLAS_CORETYPE=SkylakeX``
(LAPACK's eigenvalue routines differed there where Haswell and Sandybridge agreed), and compare
every tracking number (E_p and E_p after 2 s per joint, rms and max error, torque rms) and the
whole joint trajectory with the first run's to 1e-9 relative (issue 32; issue 29's rule: no
BLAS / CPU-dispatched NumPy on the paths a closed loop amplifies).

    python scripts/blas_independence.py [--controller PI-IDMPC] [--duration 10] [--noise 0] [--seed 0]
        [--set KEY=VALUE ...] [--loop NAME ...] [--out FILE.json] [--check]

``--loop NAME`` (repeatable; ``--loop all`` for every one): instead of one run, the named loops of
:data:`LOOPS` (the paper task clean and noisy, issue 32's real loop on each arm, with the drives'
limits and dropout, the UR5's torque limits), one report each under ``"loops"``; ``holds`` if
every one holds. The flagship's record: ``--controller flagship --loop all --out
docs/data/flagship_blas_independence.json`` (about 10 minutes on 2 cores).

``--check``: exit 1 if a number differs by more than 1e-9 relative. OpenBLAS honours
``OPENBLAS_CORETYPE`` only in its DYNAMIC_ARCH builds (NumPy's wheels are); the kernel each
process loaded is recorded (threadpoolctl), so a run where the variable had no effect shows it.
A variant's first run compiles numba's kernels for its target (about a minute, cached after).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
from datetime import UTC, datetime
from pathlib import Path

RELATIVE = 1e-9
REAL_LOOP = {
    "sensor.velocity": "differenced",
    "sensor.resolution": 9.5874e-05,
    "sensor.delay": 1,
    "friction.scale": 1,
}
"""Issue 32's real loop: a 16-bit encoder measuring position only, one period of delay, the
published joint friction."""
LOOPS: dict[str, tuple[str, dict, int]] = {
    "clean": ("the paper task, clean", {}, 0),
    "noisy": ("the paper task, noise variance 1e-3, seed 1", {"plant.noise_variance": 1e-3}, 1),
    "ur5-limits": ("the paper arm with the UR5's torque limits", {"torque_limit": [150.0] * 3 + [28.0] * 3}, 0),
    "real": ("the paper arm in the real loop", REAL_LOOP, 0),
    "real-drives": (
        "the paper arm in the real loop with a 1000 N m/s rate limit, a 20 Hz bandwidth and 10 % dropout",
        {**REAL_LOOP, "actuator.rate_limit": 1000, "actuator.bandwidth": 20, "sensor.dropout": 0.1},
        0,
    ),
    "ur5-real": ("ur5 in the real loop", {**REAL_LOOP, "arm": "ur5"}, 0),
    "alpha5-real": ("alpha5 in the real loop", {**REAL_LOOP, "arm": "alpha5"}, 0),
    "iiwa14-real": ("the 7-joint iiwa14 in the real loop", {**REAL_LOOP, "arm": "examples/urdf/iiwa14.urdf"}, 0),
}
"""``--loop``'s choices: name -> (what it is, its settings, its seed)."""
VARIANTS = {
    "OpenBLAS Haswell": {"OPENBLAS_CORETYPE": "Haswell"},
    "OpenBLAS Sandybridge, numba generic": {"OPENBLAS_CORETYPE": "Sandybridge", "NUMBA_CPU_NAME": "generic"},
}
CHILD = """
import json, sys
import numpy as np
try:
    from threadpoolctl import threadpool_info
except ImportError:  # the bench extra's; without it the kernel is not recorded
    threadpool_info = list
from hydroarm.sim.experiment import ExperimentConfig, run_experiment, with_overrides
from hydroarm.sim.runner import tracking_metrics
settings = json.loads(sys.argv[3])
config = with_overrides(ExperimentConfig(duration=float(sys.argv[2])), settings)
traj = run_experiment(config, sys.argv[1], seed=int(sys.argv[4]))
metrics = tracking_metrics(traj)
metrics.pop("time_to_band")  # a sample time, not a measured number
kernels = sorted({str(lib.get("architecture")) for lib in threadpool_info() if lib.get("internal_api") == "openblas"})
print(json.dumps({"metrics": metrics, "q": np.asarray(traj.q).tolist(), "openblas": kernels}))
"""


def run_variant(controller: str, duration: float, env: dict[str, str], settings: dict | None = None, seed: int = 0):
    """One run in a fresh process with ``env`` added (``settings``: overrides, dotted keys; ``seed``:
    the noise's): its metrics, trajectory q and OpenBLAS kernel."""
    full = {**os.environ, "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", **env}
    argv = [sys.executable, "-c", CHILD, controller, str(duration), json.dumps(settings or {}), str(seed)]
    done = subprocess.run(argv, env=full, capture_output=True, text=True, check=False)
    if done.returncode != 0:
        raise SystemExit(f"the run under {env} failed:\n{done.stderr[-2000:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def largest_relative(a, b) -> tuple[float, int]:
    """(largest |a - b| / max(|a|, |b|) over the numbers of two nested lists, how many differ)."""
    if isinstance(a, list):
        pairs = [largest_relative(x, y) for x, y in zip(a, b, strict=True)]
        return max((p[0] for p in pairs), default=0.0), sum(p[1] for p in pairs)
    if isinstance(a, bool) or a == b or (a != a and b != b):  # equal, or NaN in both (E_p after 2 s of a shorter run)
        return 0.0, 0
    return abs(a - b) / max(abs(a), abs(b)), 1


def compare(reference: dict, other: dict) -> dict[str, dict]:
    """Per number (``Ep``, ``Ep_steady``, ..., ``q``): the largest relative difference, how many differ."""
    out = {}
    for key, value in reference["metrics"].items():
        worst, differ = largest_relative(value, other["metrics"][key])
        out[key] = {"max_relative": worst, "differ": differ}
    worst, differ = largest_relative(reference["q"], other["q"])
    out["q"] = {"max_relative": worst, "differ": differ}
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--controller", default="PI-IDMPC")
    parser.add_argument("--duration", type=float, default=10.0)
    parser.add_argument("--out", type=Path)
    parser.add_argument("--noise", type=float, default=0.0, help="measurement noise variance (plant.noise_variance)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="a setting (JSON value)")
    parser.add_argument("--loop", action="append", default=[], metavar="NAME", help="a loop of LOOPS, or 'all'")
    parser.add_argument("--check", action="store_true")
    args = parser.parse_args()
    settings = {"plant.noise_variance": args.noise} if args.noise else {}
    for item in args.set:
        key, _, value = item.partition("=")
        try:
            settings[key] = json.loads(value)
        except json.JSONDecodeError:
            settings[key] = value
    if args.loop:
        names = list(LOOPS) if "all" in args.loop else args.loop
        unknown = [name for name in names if name not in LOOPS]
        if unknown:
            parser.error(f"--loop: unknown {unknown}; choose from {list(LOOPS)} or 'all'")
        reports = {}
        for name in names:
            what, loop_settings, seed = LOOPS[name]
            reports[name] = {"loop": what, **check(args.controller, args.duration, {**loop_settings, **settings}, seed)}
            print(f"{name}: {'holds' if reports[name]['holds'] else 'DIFFERS'}", file=sys.stderr, flush=True)
        report = {"controller": args.controller, "holds": all(r["holds"] for r in reports.values()), "loops": reports}
    else:
        report = check(args.controller, args.duration, settings, args.seed)
    report["measured"] = {"date": datetime.now(UTC).isoformat(timespec="seconds"), "cpu": cpu_name()}
    text = json.dumps(report, indent=1)
    print(text)
    if args.out is not None:
        args.out.write_text(text + "\n")
    return 1 if args.check and not report["holds"] else 0


def cpu_name() -> str:
    """The CPU's model name (Linux: /proc/cpuinfo), else the platform's processor string."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.partition(":")[2].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def check(controller: str, duration: float, settings: dict, seed: int) -> dict:
    """One controller's run under every one of :func:`variants`, each compared with the first (the
    report ``--out`` writes; ``numbers``: the largest difference over the variants)."""
    kinds = variants()
    runs = {label: run_variant(controller, duration, env, settings, seed) for label, env in kinds.items()}
    (ref_label, reference), *others = runs.items()
    compared = {label: compare(reference, other) for label, other in others}
    rows = {
        key: {
            "max_relative": max(c[key]["max_relative"] for c in compared.values()),
            "differ": max(c[key]["differ"] for c in compared.values()),
        }
        for key in next(iter(compared.values()))
    }
    ep = reference["metrics"]["Ep"]
    return {
        "controller": controller,
        "duration_s": duration,
        "settings": settings,
        "seed": seed,
        "reference": {"label": ref_label, "env": kinds[ref_label], "openblas": reference["openblas"]},
        "variants": [{"label": label, "env": kinds[label], "openblas": other["openblas"]} for label, other in others],
        "Ep_mean": sum(ep) / len(ep),
        "diverged": bool(reference["metrics"]["diverged"]),
        "numbers": rows,
        "holds": all(row["max_relative"] <= RELATIVE for row in rows.values()),
    }


def variants() -> dict[str, dict[str, str]]:
    """:data:`VARIANTS`, and OpenBLAS's SkylakeX kernel (AVX-512) where the CPU has AVX-512."""
    try:
        avx512 = "avx512f" in Path("/proc/cpuinfo").read_text()
    except OSError:
        avx512 = False
    return {**VARIANTS, **({"OpenBLAS SkylakeX (AVX-512)": {"OPENBLAS_CORETYPE": "SkylakeX"}} if avx512 else {})}


if __name__ == "__main__":
    raise SystemExit(main())
