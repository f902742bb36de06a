"""The planner's process stalled: when, how long, and what every thread was doing.

On the wall clock a client whose process stops for a few tenths of a second stops planning, recording and
estimating all at once (stop 76 read one: 0.23–0.31 s with no IMU sample, no pose, no plan, in a GPU client;
its relay, then a thread of the same process, sent nothing and the robot fell). A thread that waits on a lock
cannot tell what holds it; the one that holds the interpreter lock in a long C call leaves no trace in Python.
:class:`StallWatch` tells both:

* a heartbeat thread wakes every ``period`` and, like every thread of the process, needs the interpreter lock
  to run: a gap between two beats longer than ``after`` is a stall of the process (or, on an overloaded
  machine, of its CPUs), kept as (start, length) on :func:`time.monotonic`;
* before each sleep it re-arms :func:`faulthandler.dump_traceback_later` to ``after``: that timer runs in C
  without the interpreter lock, so when the heartbeat misses it, the Python stack of every thread is written
  to ``file`` *during* the stall — the thread that holds the lock is the one not waiting (its top frame is
  the call into C that holds it). Each dump is followed by a line giving the stall's length once it ended
  and the threads' names by id.

The timer is the process's only one (:mod:`faulthandler` keeps one): a watch replaces another, and
``pytest --faulthandler-timeout`` would be replaced while one runs.
"""

from __future__ import annotations

import faulthandler
import threading
import time
from pathlib import Path

PERIOD = 0.02  # the heartbeat's period [s]
AFTER = 0.15  # a gap between beats longer than this is a stall [s]: 7 beats missed


class StallWatch:
    """Notice and trace stalls of this process (module doc).

    Args:
        after: a gap between two heartbeats longer than this [s] is a stall (> ``period``).
        file: where the threads' stacks go at each stall, opened for appending (None: stalls are only
            counted, nothing dumped).
        period: the heartbeat's period [s].
    Raises:
        ValueError: ``after`` not above ``period``, or ``period`` not positive.
        OSError: ``file`` cannot be opened.

    Use as a context manager, or :meth:`start` and :meth:`close`; :meth:`take` hands out the stalls ended
    since the last call as ``(start, length)`` pairs [s, on :func:`time.monotonic`].
    """

    def __init__(self, after: float = AFTER, file: str | Path | None = None, period: float = PERIOD):
        if not period > 0 or not after > period:
            raise ValueError(f"a stall watch needs 0 < period < after, got period {period} s, after {after} s")
        self.after, self.period = float(after), float(period)
        self.path = None if file is None else Path(file)
        self._file = None if file is None else open(file, "a", buffering=1)
        self._stop = threading.Event()
        self._lock = threading.Lock()
        self._new: list[tuple[float, float]] = []
        self.stalls: list[tuple[float, float]] = []  # every stall so far: (start, length) [s]
        self._thread = threading.Thread(target=self._beat, name="amhe-stall-watch", daemon=True)

    def start(self) -> "StallWatch":
        self._thread.start()
        return self

    def _beat(self) -> None:
        last = time.monotonic()
        while not self._stop.is_set():
            if self._file is not None:
                faulthandler.dump_traceback_later(self.after, repeat=False, file=self._file)
            self._stop.wait(self.period)
            now = time.monotonic()
            if now - last > self.after:
                with self._lock:
                    self._new.append((last, now - last))
                    self.stalls.append((last, now - last))
                if self._file is not None:  # the threads by name: the stacks above name them by id alone
                    names = ", ".join(f"{t.ident:#018x} {t.name}" for t in threading.enumerate())
                    self._file.write(f"-- the stall above: {now - last:.3f} s, ended at monotonic {now:.3f} s; "
                                     f"threads: {names}\n")
            last = now
        if self._file is not None:
            faulthandler.cancel_dump_traceback_later()

    def take(self) -> list[tuple[float, float]]:
        """The stalls that ended since the last call: ``(start, length)`` [s, :func:`time.monotonic`]."""
        with self._lock:
            out, self._new = self._new, []
        return out

    def close(self) -> None:
        """Stop the heartbeat (and the timer); close the file, removed when no stall was written to it."""
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join()
        if self._file is not None:
            self._file.close()
            self._file = None
            if not self.stalls and self.path.exists() and self.path.stat().st_size == 0:
                self.path.unlink()

    def __enter__(self) -> "StallWatch":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.close()
