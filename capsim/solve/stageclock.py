"""The per-stage split of one velocity evaluation (``capsim bench`` prints it).

One clock per discretisation, shared by the membrane force and the model that
use it: each entry point starts it, each stage ends with ``lap(name)``, which
adds the seconds since the previous lap (or the start) to that stage. Laps are
sequential, so the stages add up to the evaluation and nothing is counted
twice; a caller laps before calling an entry point that starts the clock again.
"""

from __future__ import annotations

from time import perf_counter


class StageClock:
    __slots__ = ("times", "_t")

    def __init__(self) -> None:
        self.times: dict[str, float] = {}
        self._t = perf_counter()

    def start(self) -> None:
        self._t = perf_counter()

    def lap(self, name: str) -> None:
        t = perf_counter()
        self.times[name] = self.times.get(name, 0.0) + (t - self._t)
        self._t = t

    def reset(self) -> None:
        self.times.clear()
