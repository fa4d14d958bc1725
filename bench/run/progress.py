"""The progress bar of a running job."""

from __future__ import annotations

import sys
import threading
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from bench.run.loop import Budget


class Progress:
    """A tqdm bar per job on stderr: evaluations (of the budget), best f, rate and ETA.

    A timer redraws it every ``every_s`` seconds even while one batch runs long, so no phase
    of the run loop is silent for longer than that.
    """

    def __init__(self, label: str, budget: Budget, every_s: float, enabled: bool, initial: int = 0) -> None:
        from tqdm import tqdm

        self.bar = tqdm(total=budget.evals, initial=initial, desc=label, unit="eval", file=sys.stderr,
                        disable=not enabled, dynamic_ncols=True, mininterval=min(every_s, 1.0), leave=True)
        self._stop = threading.Event()
        self._every_s = every_s
        self._best_f = None
        if enabled:
            threading.Thread(target=self._redraw, daemon=True, name="bench-progress").start()

    def _redraw(self) -> None:
        while not self._stop.wait(self._every_s):
            self.bar.refresh()

    def update(self, n: int, best_f: float) -> None:
        if best_f != self._best_f:  # formatting the postfix costs ~50 us: only when it changes
            self._best_f = best_f
            self.bar.set_postfix_str(f"best f {best_f:.6g}", refresh=False)
        self.bar.update(n)

    def close(self) -> None:
        self._stop.set()
        self.bar.close()
