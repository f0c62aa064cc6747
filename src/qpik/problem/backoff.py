"""When to try again something that just failed: a closed form whose answer crossed a
limit, a solver that failed on a step. The problem changes little between steps, so what
failed most likely fails again: the next few steps skip it, twice as many after each
failure that follows, and a success brings the pause back to its start."""

from __future__ import annotations

# Steps skipped after a failure, doubled while failures follow, up to the maximum.
PAUSE = 8
PAUSE_MAX = 32


class Backoff:
    """Skips ``PAUSE`` steps after a failure, doubled while failures follow (at most
    ``PAUSE_MAX``); a hot loop may test ``skip`` itself, as :meth:`ready` does."""

    def __init__(self) -> None:
        self.skip = 0  # steps left before the next attempt
        self.next = PAUSE  # the pause after the next failure

    def ready(self) -> bool:
        """Whether to try this step (if not, one step of the pause is used up)."""
        if self.skip:
            self.skip -= 1
            return False
        return True

    def succeeded(self) -> None:
        self.next = PAUSE

    def failed(self) -> None:
        self.skip = self.next
        self.next = min(2 * self.next, PAUSE_MAX)
