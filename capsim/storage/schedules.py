"""When the run writes: snapshot times and checkpoint cadence.

Both are small state machines with ``state()`` / ``restore()`` so that a
resumed run writes its snapshots at the same times as an uninterrupted one.
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass


@dataclass
class SnapshotSchedule:
    """A full snapshot of the positions every ``every`` of kt (and at the end).

    ``next_time`` is also where the integrator clips its steps, so that
    snapshots fall on the exact times.
    """

    every: float
    next_time: float = 0.0  # the rest shape is the first snapshot
    last_time: float = -1.0
    count: int = 0

    def due(self, t: float, tolerance: float) -> bool:
        return t >= self.next_time - tolerance

    def taken(self, t: float) -> None:
        """A snapshot was written at t."""
        self.last_time = t
        self.count += 1
        self.next_time = self.every if self.count == 1 else self.next_time + self.every

    def state(self) -> dict[str, float]:
        return {k: v for k, v in asdict(self).items() if k != "every"}

    def restore(self, state: dict[str, float]) -> None:
        self.next_time, self.last_time, self.count = (float(state["next_time"]), float(state["last_time"]),
                                                      int(state["count"]))


@dataclass
class CheckpointSchedule:
    """A restart checkpoint every ``every_s`` seconds of wall time, and every ``every_steps`` accepted
    steps where that is set.

    By the wall time by default: what a killed run redoes is time, and a step costs 1 ms at level 1 and
    a second at level 5 (every 50 steps, the old default, wrote a level-2 run's checkpoint every
    0.3 s, ~1.5 % of a short run for a kill that would cost that 0.3 s)."""

    every_steps: int | None
    every_s: float
    last_steps: int = 0
    last_wall: float = 0.0

    def __post_init__(self) -> None:
        self.last_wall = time.perf_counter()

    def due(self, steps: int) -> bool:
        return ((self.every_steps is not None and steps - self.last_steps >= self.every_steps)
                or time.perf_counter() - self.last_wall >= self.every_s)

    def taken(self, steps: int) -> None:
        self.last_steps, self.last_wall = steps, time.perf_counter()


def end_tolerance(t_end: float) -> float:
    """Round-off in the sum of step sizes: t within this of t_end is the end."""
    return 1e-12 * max(1.0, t_end)
