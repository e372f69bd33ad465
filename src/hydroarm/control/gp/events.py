"""What a `SlidingWindowGP` reports: the fault events its calls return (:data:`FAULTS`) and
the counters it keeps (:class:`GPStats`)."""

from __future__ import annotations

from dataclasses import asdict, dataclass

__all__ = ["FAULTS", "GPStats"]

FAULTS = ("gp_jittered", "gp_cholesky_fallback", "gp_prior_prediction")
"""The fault events a `SlidingWindowGP` call can return, in the order it returns them (names of
:data:`hydroarm.control.interface.FAULT_EVENTS`): one per output and factorisation that needed
extra jitter, one per output whose Cholesky failed even so, one per output predicted from its
prior."""


@dataclass
class GPStats:
    """Counters of `SlidingWindowGP` events (summed over outputs)."""

    n_updates: int = 0  # update_hyperparameters calls that ran steps
    n_accepted_steps: int = 0  # per output and step, LML did not decrease
    n_rejected_steps: int = 0  # per output and step, every halving decreased the LML (theta kept)
    n_step_halvings: int = 0
    n_jittered_factorizations: int = 0  # Cholesky succeeded only with extra diagonal
    n_cholesky_fallbacks: int = 0  # Cholesky failed even with max jitter: previous theta / prior kept
    n_prior_predictions: int = 0  # outputs predicted from the prior because no factor existed
    n_full_factorizations: int = 0  # stacked (all outputs) full factorisations of a window
    n_incremental_updates: int = 0  # O(N^2) window updates of the factor

    def count_steps(self, full_factorizations: int, accepted: int, halvings: int, rejected: int) -> None:
        """Add one hyperparameter update's factorisations and step outcomes."""
        self.n_full_factorizations += full_factorizations
        self.n_accepted_steps += accepted
        self.n_step_halvings += halvings
        self.n_rejected_steps += rejected

    def as_dict(self) -> dict[str, int]:
        return asdict(self)
