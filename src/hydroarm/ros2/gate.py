"""What a node does with what arrives on the graph: every message checked, a bad one dropped and
counted, never a crash.

:class:`CommandGate` stands between ``/<controller>/commands`` and the simulated drives: a command
of the wrong length or with a non-finite value is dropped (``wrong_length``, ``non_finite``); when
no good command is newer than ``command_timeout`` the drives get the last good one
(``on_stale = "hold"``) or zero torque (``"zero"``), and the step is counted ``stale`` (before any
command: zero torque, counted ``missing``).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

COUNTS = ("received", "accepted", "wrong_length", "non_finite", "stale", "missing")
"""What the gate counts (module docstring)."""


@dataclass
class CommandGate:
    """The drives' command from the graph for ``n`` joints (module docstring); times in s."""

    n: int
    timeout: float
    on_stale: str = "hold"
    counts: dict[str, int] = field(default_factory=lambda: dict.fromkeys(COUNTS, 0))

    def __post_init__(self) -> None:
        self.last = np.zeros(self.n)
        self.last_time: float | None = None

    def offer(self, data, now: float) -> bool:
        """A command's values (any sequence) received at ``now``; True if accepted."""
        self.counts["received"] += 1
        values = np.asarray(list(data), dtype=float)
        if values.shape != (self.n,):
            self.counts["wrong_length"] += 1
            return False
        if not np.all(np.isfinite(values)):
            self.counts["non_finite"] += 1
            return False
        self.counts["accepted"] += 1
        self.last, self.last_time = values, now
        return True

    def torque(self, now: float) -> np.ndarray:
        """The torque (n,) N m the drives apply at ``now``."""
        if self.last_time is None:
            self.counts["missing"] += 1
            return np.zeros(self.n)
        if now - self.last_time > self.timeout:
            self.counts["stale"] += 1
            return self.last.copy() if self.on_stale == "hold" else np.zeros(self.n)
        return self.last.copy()
