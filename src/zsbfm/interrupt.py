"""SIGINT and SIGTERM end a run between two chunks, never inside a write.

While a run trains (zsbfm.train, zsbfm.sweep), `StopSignals` turns the first SIGINT or
SIGTERM into a request: the chunk in flight finishes (a compiled program cannot be cut
short anyway), its metrics line and checkpoint are written, and the driver raises
`Interrupted`, which the command line reports in one line with exit code 128 + the signal
(130, 143). Run again, the run resumes from that checkpoint and ends bit-identical to an
uninterrupted one. A second signal is not deferred: it acts as it would have without
zsbfm (SIGINT raises KeyboardInterrupt at once, SIGTERM ends the process).
"""

from __future__ import annotations

import signal
import threading

SIGNALS = (signal.SIGINT, signal.SIGTERM)


class Interrupted(KeyboardInterrupt):
    """A run stopped by a signal at a chunk boundary, everything up to `chunk` written."""

    def __init__(self, signum: int, chunk: int, num_chunks: int):
        self.signum, self.chunk = signum, chunk
        self.exit_code = 128 + signum
        name = signal.Signals(signum).name
        if chunk == 0:
            super().__init__(f"{name}: stopped before the first chunk ended; nothing was trained")
            return
        done = (f"training done ({chunk}/{num_chunks} chunks), not yet evaluated" if chunk == num_chunks
                else f"after chunk {chunk}/{num_chunks}")
        super().__init__(f"{name}: stopped {done}; its checkpoint is written: run the same "
                         "command again to resume")


class StopSignals:
    """Context manager deferring SIGINT and SIGTERM: the first one sets `signum`, which the
    training loop reads between chunks. Only the main thread can install signal handlers,
    so elsewhere (a thread of a notebook, a test worker thread) it leaves them alone."""

    def __init__(self):
        self.signum: int | None = None
        self._previous: dict = {}

    def __enter__(self) -> "StopSignals":
        if threading.current_thread() is threading.main_thread():
            self._previous = {s: signal.signal(s, self._request) for s in SIGNALS}
        return self

    def _request(self, signum, frame) -> None:
        self.signum = signum
        self._restore()  # a second signal acts at once

    def _restore(self) -> None:
        for s, handler in self._previous.items():
            signal.signal(s, handler)
        self._previous = {}

    def __exit__(self, *exc) -> None:
        self._restore()

    def check(self, chunk: int, num_chunks: int) -> None:
        """Raise Interrupted if a signal came (call it where stopping leaves nothing half-done)."""
        if self.signum is not None:
            raise Interrupted(self.signum, chunk, num_chunks)
