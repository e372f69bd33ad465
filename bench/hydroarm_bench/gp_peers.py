"""Section 2b: our GP step against scikit-learn and GPyTorch on the same closed-loop windows.

The GP-MPC's stream of ``add`` / ``predict`` calls on the paper scenario is recorded
once and replayed on a fresh :class:`~hydroarm.control.gp.SlidingWindowGP`; each timed
step is add + one hyperparameter step + prediction (all outputs). The peers fit the
same windows: scikit-learn's ``GaussianProcessRegressor`` (ConstantKernel * RBF(ARD) +
WhiteKernel, L-BFGS-B, one regressor per output) and GPyTorch's exact GP (6-batch, a
few Adam steps). The predictive means at our hyperparameters are checked against
scikit-learn's.
"""

from __future__ import annotations

import math
import time
import warnings

import numpy as np

from hydroarm_bench.loop import paper_config, paper_experiment
from hydroarm_bench.stats import FULL_SAMPLES, TARGETS, missing, ratio, stats_ms, version


def record_gp_stream(duration: float = 10.0) -> list:
    """The GP's add / predict calls of a GP-MPC closed loop on the paper task, in order."""
    events: list = []
    experiment = paper_experiment("GP-MPC", duration)
    gp = experiment.controller.gp
    add, predict = gp.update, gp.predict

    def recording_add(x, y):
        events.append(("add", np.array(x, dtype=float), np.array(y, dtype=float)))
        return add(x, y)

    def recording_predict(x, **kwargs):
        events.append(("predict", np.array(x, dtype=float)))
        return predict(x, **kwargs)

    gp.update, gp.predict = recording_add, recording_predict
    experiment.run(0)
    return events


def replay_ours(events, gp_config, n_inputs: int, n_outputs: int, max_steps: int | None = None):
    """Replay the stream on a fresh SlidingWindowGP: per step (add + update + predict) seconds,
    the windows (X, Y, theta, x*, our mean) at each timed step (full windows only)."""
    from hydroarm.control.gp import SlidingWindowGP

    gp = SlidingWindowGP(n_inputs, n_outputs, gp_config)
    pending_add = 0
    step_s, windows = [], []
    add_s = 0.0
    for event in events:
        if event[0] == "add":
            start = time.perf_counter_ns()
            gp.update(event[1], event[2])
            add_s = (time.perf_counter_ns() - start) * 1e-9
            pending_add = 1
            continue
        if gp.n_samples < 2:
            continue
        start = time.perf_counter_ns()
        gp.update_hyperparameters()
        mean, _ = gp.predict(event[1])
        elapsed = (time.perf_counter_ns() - start) * 1e-9 + (add_s if pending_add else 0.0)
        pending_add = 0
        if gp.n_samples == gp_config.window:
            step_s.append(elapsed)
            windows.append((gp.window_inputs, gp.window_targets, gp.theta, event[1].copy(), mean.copy()))
            if max_steps is not None and len(step_s) >= max_steps:
                break
    return step_s, windows


def sklearn_kernel(theta: np.ndarray, gp_config, fixed: bool):
    """Our kernel in scikit-learn: C * RBF(ARD) + White, fixed at ``theta`` or within our bounds."""
    from sklearn.gaussian_process.kernels import RBF, ConstantKernel, WhiteKernel

    if fixed:
        return ConstantKernel(theta[0], "fixed") * RBF(theta[2:], "fixed") + WhiteKernel(theta[1], "fixed")
    sf2 = tuple(math.exp(b) for b in gp_config.log_sf2_bounds)
    sn2 = tuple(math.exp(b) for b in gp_config.log_sn2_bounds)
    ls = tuple(math.exp(b) for b in gp_config.log_lengthscale_bounds)
    return ConstantKernel(theta[0], sf2) * RBF(theta[2:], ls) + WhiteKernel(theta[1], sn2)


def _bench_sklearn(chosen, ours: dict, gp_config, n_inputs: int, n_outputs: int) -> dict:
    from sklearn.gaussian_process import GaussianProcessRegressor

    theta0 = np.ones(n_inputs + 2) if gp_config.theta0 is None else np.asarray(gp_config.theta0)
    worst_abs, worst_rel = 0.0, 0.0
    for X, Y, theta, x_star, mean in chosen:  # same hyperparameters: same predictive mean?
        for o in range(n_outputs):
            fixed = GaussianProcessRegressor(
                sklearn_kernel(theta[o], gp_config, True), alpha=gp_config.jitter, optimizer=None
            ).fit(X, Y[:, o])
            reference = float(fixed.predict(x_star[None])[0])
            worst_abs = max(worst_abs, abs(reference - mean[o]))
            worst_rel = max(worst_rel, abs(reference - mean[o]) / max(1.0, abs(reference)))
    seconds = []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # ConvergenceWarning at the bounds
        for X, Y, _, x_star, _ in chosen:
            start = time.perf_counter_ns()
            for o in range(n_outputs):
                model = GaussianProcessRegressor(
                    sklearn_kernel(theta0, gp_config, False), alpha=gp_config.jitter, n_restarts_optimizer=0
                ).fit(X, Y[:, o])
                model.predict(x_star[None])
            seconds.append((time.perf_counter_ns() - start) * 1e-9)
    timing = stats_ms(seconds)
    return {
        "available": True,
        "version": version("scikit-learn"),
        "definition": "6 x GaussianProcessRegressor(C*RBF(ARD)+White, L-BFGS-B from theta0 = 1, "
        "n_restarts_optimizer=0).fit + predict",
        "step_ms": timing,
        "mean_at_our_theta_max_abs_diff": worst_abs,
        "mean_at_our_theta_max_rel_diff": worst_rel,
        "agrees_to_1e-6": worst_abs <= TARGETS["gp_mean_agreement"],
        "speedup": ratio(timing["median"], ours["median"]),
    }


def _bench_gpytorch(chosen, ours: dict, n_inputs: int, n_outputs: int, adam_steps: int = 5) -> dict:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        import gpytorch
        import torch

    torch.set_num_threads(1)
    dtype = torch.float64
    batch = torch.Size([n_outputs])

    class BatchGP(gpytorch.models.ExactGP):
        def __init__(self, x, y, likelihood):
            super().__init__(x, y, likelihood)
            self.mean_module = gpytorch.means.ZeroMean(batch_shape=batch)
            self.covar_module = gpytorch.kernels.ScaleKernel(
                gpytorch.kernels.RBFKernel(ard_num_dims=n_inputs, batch_shape=batch), batch_shape=batch
            )

        def forward(self, x):
            return gpytorch.distributions.MultivariateNormal(self.mean_module(x), self.covar_module(x))

    def to_tensors(X, Y):
        x = torch.as_tensor(X, dtype=dtype).expand(n_outputs, *X.shape).contiguous()
        y = torch.as_tensor(Y.T.copy(), dtype=dtype)
        return x, y

    x, y = to_tensors(chosen[0][0], chosen[0][1])
    likelihood = gpytorch.likelihoods.GaussianLikelihood(batch_shape=batch).to(dtype)
    model = BatchGP(x, y, likelihood).to(dtype)
    optimizer = torch.optim.Adam(model.parameters(), lr=0.1)
    mll = gpytorch.mlls.ExactMarginalLogLikelihood(likelihood, model)

    def step(X, Y, x_star):
        x, y = to_tensors(X, Y)
        model.set_train_data(x, y, strict=False)
        model.train()
        likelihood.train()
        for _ in range(adam_steps):
            optimizer.zero_grad()
            loss = -mll(model(x), y).sum()
            loss.backward()
            optimizer.step()
        model.eval()
        likelihood.eval()
        with torch.no_grad(), gpytorch.settings.fast_pred_var():
            test = torch.as_tensor(x_star[None], dtype=dtype).expand(n_outputs, 1, n_inputs)
            return likelihood(model(test)).mean

    step(*chosen[0][0:2], chosen[0][3])  # warm-up
    seconds = []
    for X, Y, _, x_star, _ in chosen:
        start = time.perf_counter_ns()
        step(X, Y, x_star)
        seconds.append((time.perf_counter_ns() - start) * 1e-9)
    timing = stats_ms(seconds)
    return {
        "available": True,
        "version": version("gpytorch"),
        "torch": version("torch"),
        "definition": f"exact GP, 6-batch, float64, warm-started, {adam_steps} Adam steps (lr 0.1) + predict",
        "step_ms": timing,
        "speedup": ratio(timing["median"], ours["median"]),
    }


def bench_gp_peers(events: list, quick: bool) -> dict:
    """Our GP step vs scikit-learn and GPyTorch on the same closed-loop windows."""
    gp_config = paper_config().gp
    n_inputs, n_outputs = events[0][1].size, events[0][2].size
    replay_ours(events, gp_config, n_inputs, n_outputs)  # warm-up
    ours_s, windows = replay_ours(events, gp_config, n_inputs, n_outputs)
    ours = stats_ms(ours_s)  # measured again after the peers (load drifts); the ratios use both
    report = {
        "setting": (
            f"window {gp_config.window}, {n_inputs} inputs, {n_outputs} outputs, hyper_steps "
            f"{gp_config.hyper_steps}; windows of the GP-MPC closed loop on the paper task"
        ),
        "ours_step_ms": ours,
        "ours_definition": "add (slide the window) + update_hyperparameters + predict, all outputs",
        "peers": {},
    }
    count = 5 if quick else FULL_SAMPLES
    picks = np.linspace(0, len(windows) - 1, min(count, len(windows))).astype(int)
    chosen = [windows[i] for i in picks]

    reason = missing("sklearn")
    if reason is not None:
        report["peers"]["sklearn"] = {"available": False, "reason": reason}
    else:
        report["peers"]["sklearn"] = _bench_sklearn(chosen, ours, gp_config, n_inputs, n_outputs)

    reason = missing("torch", "gpytorch")
    if reason is not None:
        report["peers"]["gpytorch"] = {"available": False, "reason": reason}
    else:
        try:
            report["peers"]["gpytorch"] = _bench_gpytorch(chosen, ours, n_inputs, n_outputs)
        except Exception as error:  # a broken peer must not stop the suite
            report["peers"]["gpytorch"] = {"available": False, "reason": f"failed: {error!r}"}

    # ours again, after the peers: the speed-ups use the samples of both passes
    ours_s += replay_ours(events, gp_config, n_inputs, n_outputs)[0]
    ours = stats_ms(ours_s)
    report["ours_step_ms"] = ours
    for peer in report["peers"].values():
        if peer.get("available"):
            peer["speedup"] = ratio(peer["step_ms"]["median"], ours["median"])
    return report
