"""The run loop's events and the writers that subscribe to them.

The loop (``runner.run``) publishes four events, in this order:

    SetupDone                      once, the simulation built, before iteration 1
    IterationTraced(i)             after the tracing pass of iteration i
    IterationUpdated(i)            after the update rules of iteration i (rows final)
    RunFinished                    once, after the last iteration

A ``Writer`` subscribes by overriding the matching ``on_*`` methods; every
writer sees every event, on the loop's thread, in the order the writers were
given.  An output, a viewer or a Python callback is one ``Writer`` subclass;
the loop is never edited to add one.

Slow work (encoding an image, writing a file) need not stall the loop: a
handler takes what it needs from the simulation (which only the loop's
thread may touch), then passes the rest as a job to ``event.run.behind``.
Jobs run one at a time on one background thread, in the order they were
given (so outputs are never reordered), with at most ``WriteQueue.BOUND``
waiting (the loop waits when the queue is full).  A job's exception is
raised on the loop's thread at the next ``behind`` call or at the end of the
run.  A job must not touch the simulation: hand it copies (``sim.rows()``
and the event's arrays already are).

This module owns the event types and the queue; it knows no output format.
"""

from __future__ import annotations

import queue
import threading
import time
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any, Callable

from ...records import Record, record


# ---- events ------------------------------------------------------------------------

@dataclass(frozen=True)
class SetupDone:
    """The simulation exists (surfels placed, kernels bound); no iteration ran yet."""

    run: Any            # runner.Run
    handler = "on_setup_done"


@dataclass(frozen=True)
class IterationTraced:
    """The gamma-tons of ``iteration`` were traced; update rules not yet run."""

    run: Any
    iteration: int
    stats: dict         # Simulation.trace's result (counts, seconds, non-finite list)
    handler = "on_iteration_traced"


@dataclass(frozen=True)
class IterationUpdated:
    """``iteration`` is complete: ``rows`` is every surfel's row after its update rules."""

    run: Any
    iteration: int
    rows: Any           # float32 [surfels, row width], a copy
    properties: dict    # property name -> float32 column (0 where a surface lacks it)
    record: dict        # this iteration's entry of summary["iterations"]
    handler = "on_iteration_updated"


@dataclass(frozen=True)
class RunFinished:
    run: Any
    summary: dict
    handler = "on_run_finished"


Event = SetupDone | IterationTraced | IterationUpdated | RunFinished


class Writer:
    """Base of every output; override the events you need (the rest do nothing)."""

    def on_setup_done(self, event: SetupDone) -> None:
        pass

    def on_iteration_traced(self, event: IterationTraced) -> None:
        pass

    def on_iteration_updated(self, event: IterationUpdated) -> None:
        pass

    def on_run_finished(self, event: RunFinished) -> None:
        pass


class CallbackWriter(Writer):
    """Calls ``callback(event)`` for every event (or only those of ``events``):
    how a Python program follows a run, e.g.
    ``run(effect, opts, writers=[CallbackWriter(print, events=(IterationUpdated,))])``."""

    def __init__(self, callback: Callable[[Event], None], events: tuple[type, ...] | None = None):
        self.callback = callback
        self.events = events

    def _call(self, event) -> None:
        if self.events is None or isinstance(event, self.events):
            self.callback(event)

    on_setup_done = on_iteration_traced = on_iteration_updated = on_run_finished = _call


def publish(writers: list[Writer], event: Event) -> None:
    for writer in writers:
        getattr(writer, event.handler)(event)


# ---- jobs behind the loop ----------------------------------------------------------------

class Timings:
    """Seconds spent per kind of output ("maps", "renders", ...), summed over
    the loop's thread and the writer's (summary.json's ``output_seconds``):
    busy time, which overlaps the loop where it runs behind it."""

    def __init__(self):
        self._seconds: dict[str, float] = {}
        self._lock = threading.Lock()

    @contextmanager
    def timed(self, kind: str):
        t0 = time.perf_counter()
        try:
            yield
        finally:
            self.add(kind, time.perf_counter() - t0)

    def call(self, kind: str, fn: Callable, *args, **kwargs):
        """``fn(*args, **kwargs)``, its time counted under ``kind``."""
        with self.timed(kind):
            return fn(*args, **kwargs)

    def add(self, kind: str, seconds: float) -> None:
        with self._lock:
            self._seconds[kind] = self._seconds.get(kind, 0.0) + seconds

    def snapshot(self) -> dict[str, float]:
        with self._lock:
            return dict(self._seconds)


@record
class WriteQueue(Record):
    """One background thread running jobs in order; bounded.  Use as a context
    manager: leaving it waits for every job given so far (also when the loop
    failed), then raises the first job's error if the loop did not fail."""

    BOUND = 4
    _jobs: queue.Queue = field(default_factory=lambda: queue.Queue(maxsize=WriteQueue.BOUND))
    _thread: threading.Thread | None = None
    _error: BaseException | None = None   # the first failed job's; later jobs are skipped
    _raised: bool = False
    timings: Timings = field(default_factory=Timings)   # what the outputs cost, by kind

    def timed(self, kind: str, job: Callable, *args, **kwargs) -> None:
        """``self(job, ...)``, its time counted under ``kind`` in ``timings``."""
        self(self.timings.call, kind, job, *args, **kwargs)

    def __call__(self, job: Callable, *args, **kwargs) -> None:
        """Run ``job(*args, **kwargs)`` behind the loop, after every earlier job."""
        self._raise()
        if self._thread is None:
            self._thread = threading.Thread(target=self._work, name="gamma-writer", daemon=True)
            self._thread.start()
        if self._jobs.full():          # the loop waits for the writer: count it
            with self.timings.timed("waiting for the writer"):
                self._jobs.put((job, args, kwargs))
        else:
            self._jobs.put((job, args, kwargs))

    def _work(self) -> None:
        while True:
            item = self._jobs.get()
            if item is None:
                return
            job, args, kwargs = item
            if self._error is None:   # after a failure the rest are skipped
                try:
                    job(*args, **kwargs)
                except BaseException as err:  # noqa: BLE001 - re-raised on the loop's thread
                    self._error = err
            del item, job, args, kwargs   # (a picture's view, say) not held while the next is awaited

    def _raise(self) -> None:
        if self._error is not None and not self._raised:
            self._raised = True
            raise self._error

    def drain(self) -> None:
        """Wait for every job given so far; the thread ends."""
        if self._thread is not None:
            self._jobs.put(None)
            self._thread.join()
            self._thread = None

    def __enter__(self) -> "WriteQueue":
        return self

    def __exit__(self, kind, value, tb) -> None:
        self.drain()
        if kind is None:
            self._raise()
