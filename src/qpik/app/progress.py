"""Progress bars on stderr for the commands and benchmarks that run longer than a moment.

A bar shows only where someone can see it: on a terminal, and not with ``--quiet``.
Piped or redirected output (CI logs, ``2> file``) stays free of carriage-return noise.
tqdm is imported only when a bar is actually drawn; without it (the ``cli`` extra) there
are no bars.
"""

from __future__ import annotations

import sys
from typing import Callable


def wanted(quiet: bool = False) -> bool:
    """Whether to draw bars: stderr is a terminal, the user did not ask for quiet, and tqdm
    is installed."""
    from ..extras import installed

    return not quiet and sys.stderr.isatty() and installed("tqdm")


class StepBars:
    """One tqdm bar per labelled run, fed by ``simulate``'s ``progress(k, steps)`` callbacks.

    ``bars.callback(label)`` gives the ``(k, steps)`` callback of one run; ``bars(label,
    k, steps)`` does the same in one call (the shape :func:`qpik.app.runs.compare` takes).
    A new label closes the previous bar. Disabled, every call is a no-op.
    """

    def __init__(self, enabled: bool, unit: str = "step"):
        self.enabled = enabled
        self.unit = unit
        self._bar = None
        self._label: str | None = None

    def __call__(self, label: str, k: int, total: int) -> None:
        if not self.enabled:
            return
        if label != self._label or self._bar is None:
            self.close()
            from tqdm import tqdm

            tqdm.monitor_interval = 0  # no monitor thread taking the GIL amid timed steps
            self._bar = tqdm(total=total, desc=label, unit=self.unit, file=sys.stderr, leave=False,
                             dynamic_ncols=True, mininterval=0.2)
            self._label = label
        self._bar.update(k - self._bar.n)

    def callback(self, label: str) -> Callable[[int, int], None] | None:
        """The ``progress(k, steps)`` callback of one run (None when disabled: zero cost)."""
        if not self.enabled:
            return None
        return lambda k, total: self(label, k, total)

    def close(self) -> None:
        if self._bar is not None:
            self._bar.close()
        self._bar, self._label = None, None

    def __enter__(self) -> StepBars:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def iterate(items, *, desc: str, enabled: bool, total: int | None = None, unit: str = "it"):
    """``items`` wrapped in a tqdm bar on stderr when ``enabled``, else unchanged."""
    if not enabled:
        return items
    from tqdm import tqdm

    return tqdm(items, desc=desc, total=total, unit=unit, file=sys.stderr, leave=False, dynamic_ncols=True)
