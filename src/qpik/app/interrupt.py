"""Ctrl-C that always stops a command, even inside a solver that catches SIGINT itself.

OSQP (1.x) installs its own SIGINT handler for the duration of every solve: a Ctrl-C that
lands there sets OSQP's private flag, the solve returns "interrupted" and Python never
hears of it, so a rollout would go on (and the comparison would record a truncated run).
Most of a hexapod step with OSQP is spent in that solve, so most Ctrl-C were lost.

The fix does not depend on any solver: while a command runs, SIGINT is blocked in every
thread of the process, so no handler (Python's or a C library's) is ever invoked for it;
a watcher thread takes it synchronously with ``sigwait`` and raises ``KeyboardInterrupt``
in the main thread (``_thread.interrupt_main``), which Python delivers at the next
bytecode boundary: after the current solve or step returns, within microseconds.

SIGTERM (``kill``, a job scheduler, a container stopping) is taken the same way and
raised as :class:`Terminated`, a ``KeyboardInterrupt``, so the same clean-up runs; the
command then exits with 143 (128 + SIGTERM) instead of 130.

Inside :meth:`InterruptGuard.shielded` (moving finished files into place, removing a
partial output) a Ctrl-C is held back until the block ends, so the output is all or none.

The mask is per thread and inherited at thread creation, so the guard must be entered
before any other thread starts: NumPy's BLAS pool starts at ``import numpy``, and a
thread born unguarded would take the SIGINT (then OSQP's handler can swallow it again).
``qpik``'s ``main`` enters it first, before anything numerical is imported.

POSIX only; elsewhere (or off the main thread) the guard does nothing and Python's own
handling applies.
"""

from __future__ import annotations

import _thread
import signal
import threading
from contextlib import contextmanager
from typing import Iterator

_SIGNALS = {signal.SIGINT, signal.SIGTERM}


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised in the main thread like Ctrl-C so every clean-up path runs."""


def _raise_terminated(signum, frame):
    raise Terminated


class InterruptGuard:
    """Route SIGINT and SIGTERM through a watcher thread for the lifetime of a ``with`` block."""

    def __init__(self):
        self.interrupted = False
        self._active = (hasattr(signal, "pthread_sigmask") and hasattr(signal, "sigwait")
                        and threading.current_thread() is threading.main_thread())
        self._lock = threading.Lock()
        self._shield_depth = 0
        self._pending: int | None = None  # the signal held back by a shield
        self._closing = False
        self._watcher: threading.Thread | None = None
        self._previous_mask = None
        self._previous_term_handler = None

    def __enter__(self) -> InterruptGuard:
        if self._active:
            # Block before the thread starts: it inherits the mask, and so does every
            # thread started later (tqdm's monitor, solver pools).
            self._previous_mask = signal.pthread_sigmask(signal.SIG_BLOCK, _SIGNALS)
            # Only interrupt_main(SIGTERM) calls it: SIGTERM itself is blocked everywhere.
            self._previous_term_handler = signal.signal(signal.SIGTERM, _raise_terminated)
            self._watcher = threading.Thread(target=self._watch, name="qpik-sigint", daemon=True)
            self._watcher.start()
        return self

    def __exit__(self, *exc) -> None:
        if not self._active:
            return
        with self._lock:
            self._closing = True
        signal.pthread_kill(self._watcher.ident, signal.SIGINT)  # wakes sigwait; ignored as closing
        self._watcher.join()
        # A Ctrl-C that arrived after the watcher stopped is still pending: drop it, the
        # command is over.
        while _SIGNALS & signal.sigpending():
            signal.sigwait(_SIGNALS)
        signal.signal(signal.SIGTERM, self._previous_term_handler)
        signal.pthread_sigmask(signal.SIG_SETMASK, self._previous_mask)

    def _watch(self) -> None:
        while True:
            signum = signal.sigwait(_SIGNALS)
            with self._lock:
                if self._closing:
                    return
                self.interrupted = True
                if self._shield_depth:
                    self._pending = signum
                    continue
                _thread.interrupt_main(signum)  # under the lock: never after __exit__

    @contextmanager
    def shielded(self) -> Iterator[None]:
        """Hold a Ctrl-C (or SIGTERM) back until the block is done, then raise it."""
        with self._lock:
            self._shield_depth += 1
        try:
            yield
        finally:
            with self._lock:
                self._shield_depth -= 1
                held = self._pending if self._shield_depth == 0 else None
                if held is not None:
                    self._pending = None
            if held is not None:
                raise Terminated if held == signal.SIGTERM else KeyboardInterrupt
