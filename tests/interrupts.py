"""Progress callbacks standing in for Ctrl-C: a run is interrupted once it has taken a number
of accepted steps, or reached a time (run_case's progress receives ``{t, step, ...}``)."""

from __future__ import annotations


class InterruptAfter:
    """KeyboardInterrupt at the report of accepted step `steps`."""

    def __init__(self, steps: int) -> None:
        self.steps = steps

    def __call__(self, state: dict) -> None:
        if state["step"] >= self.steps:
            raise KeyboardInterrupt


class InterruptAt:
    """KeyboardInterrupt at the first report at or after time `t`."""

    def __init__(self, t: float) -> None:
        self.t = t

    def __call__(self, state: dict) -> None:
        if state["t"] >= self.t:
            raise KeyboardInterrupt
