"""Does a controller's run depend on the BLAS kernel or numba's CPU target? Run it (default: the
flagship candidate PI-IDMPC, 10 s of the paper task, clean) in fresh processes under
``OPENBLAS_CORETYPE=Haswell`` and under ``OPENBLAS_CORETYPE=Sandybridge NUMBA_CPU_NAME=generic``
(no FMA, no AVX2 in either library), and compare every tracking number (E_p and E_p after 2 s per
joint, rms and max error, torque rms) and the whole joint trajectory to 1e-9 relative
(issue 32; issue 29's rule: no BLAS / CPU-dispatched NumPy on the paths a closed loop amplifies).

    python scripts/blas_independence.py [--controller PI-IDMPC] [--duration 10] [--noise 0] [--seed 0]
        [--set KEY=VALUE ...] [--out FILE.json] [--check]

``--check``: exit 1 if a number differs by more than 1e-9 relative. OpenBLAS honours
``OPENBLAS_CORETYPE`` only in its DYNAMIC_ARCH builds (NumPy's wheels are); the kernel each
process loaded is recorded (threadpoolctl), so a run where the variable had no effect shows it.
A variant's first run compiles numba's kernels for its target (about a minute, cached after).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

RELATIVE = 1e-9
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
    if isinstance(a, bool) or a == b:
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
    parser.add_argument("--check", action="store_true")
    args = parser.parse_args()
    settings = {"plant.noise_variance": args.noise} if args.noise else {}
    for item in args.set:
        key, _, value = item.partition("=")
        try:
            settings[key] = json.loads(value)
        except json.JSONDecodeError:
            settings[key] = value
    runs = {
        label: run_variant(args.controller, args.duration, env, settings, args.seed) for label, env in VARIANTS.items()
    }
    (ref_label, reference), (label, other) = runs.items()
    rows = compare(reference, other)
    ep = reference["metrics"]["Ep"]
    report = {
        "controller": args.controller,
        "duration_s": args.duration,
        "settings": settings,
        "seed": args.seed,
        "reference": {"label": ref_label, "env": VARIANTS[ref_label], "openblas": reference["openblas"]},
        "variant": {"label": label, "env": VARIANTS[label], "openblas": other["openblas"]},
        "Ep_mean": sum(ep) / len(ep),
        "numbers": rows,
        "holds": all(row["max_relative"] <= RELATIVE for row in rows.values()),
    }
    text = json.dumps(report, indent=1)
    print(text)
    if args.out is not None:
        args.out.write_text(text + "\n")
    return 1 if args.check and not report["holds"] else 0


if __name__ == "__main__":
    raise SystemExit(main())
