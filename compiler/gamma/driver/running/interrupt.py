"""SIGINT and SIGTERM during a run: noticed within a fraction of a second,
even while the runtime is busy for minutes in one call.

Python runs a signal handler only on the main thread, between bytecodes;
a long C++ call (a tracing pass, surfel placement, a render) would hold it
off until it returns.  ``Interruptions.call`` therefore runs such a call on
a helper thread (the runtime releases the GIL) while the main thread waits
in short steps and raises ``Interrupted`` as soon as a signal came.  The
call then still runs: whoever catches ``Interrupted`` must not touch the
simulation again and ends the process with ``os._exit`` once its files are
written (the CLI does).  One helper thread makes a run's calls one after
another (a new thread per call cost ~1 ms each to start on the two busy
cores, twice per iteration, on the loop's critical path); a call abandoned
while running (a signal, or an error another signal's handler raised) keeps
it, and the next call gets a thread of its own; ``abandoned`` is its
outcome, and the interpreter's exit joins its thread (one that came back
from the runtime while the interpreter finalized aborted the process:
"terminate called without an active exception").  Leaving the context
joins the idle helper: a daemon thread still waiting for calls when the
interpreter finalizes would hold its frames' objects for ever.
"""

from __future__ import annotations

import queue
import signal
import threading

from ... import background
from ...background import Outcome

SIGNAL_NAMES = {signal.SIGINT: "SIGINT", signal.SIGTERM: "SIGTERM"}


class Interrupted(Exception):
    """A SIGINT or SIGTERM arrived; ``status`` is the exit status SPEC §16.2
    gives for it (128 + the signal number: 130, 143)."""

    def __init__(self, signum: int):
        self.signum = signum
        self.name = SIGNAL_NAMES.get(signum, f"signal {signum}")
        self.status = 128 + signum
        super().__init__(f"interrupted by {self.name}")


class Interruptions:
    """Context manager: SIGINT and SIGTERM are recorded (not raised where they
    land) while it is active, and ``check``/``call`` raise ``Interrupted``.
    Outside the main thread (a program running ``run`` from a thread) signals
    cannot be caught and ``call`` simply calls."""

    STEP = 0.05   # seconds between looks at the flag

    def __init__(self):
        self.signum: int | None = None
        self.busy = False              # a call was abandoned while running
        self.abandoned: Outcome | None = None   # the outcome of the last call abandoned
        self._previous: dict = {}
        self._jobs: queue.SimpleQueue | None = None   # the helper thread's, once started
        self._helper: threading.Thread | None = None

    def __enter__(self) -> "Interruptions":
        if threading.current_thread() is threading.main_thread():
            for sig in SIGNAL_NAMES:
                self._previous[sig] = signal.signal(sig, self._record)
        return self

    def __exit__(self, *exc) -> None:
        for sig, handler in self._previous.items():
            signal.signal(sig, handler)
        self._previous.clear()
        if self._jobs is not None:
            # the helper is idle (a call left running was abandoned: ``call``) and joined: a
            # daemon thread still running when the interpreter finalizes leaves what its
            # frames hold behind (nanobind reports it leaked)
            self._jobs.put(None)
            self._helper.join()
            self._jobs = self._helper = None

    def _record(self, signum, frame) -> None:
        if self.signum is None:
            self.signum = signum

    def check(self) -> None:
        if self.signum is not None:
            raise Interrupted(self.signum)

    def call(self, fn, *args, **kwargs):
        """``fn(*args, **kwargs)``, abandoned (Interrupted) if a signal comes first."""
        self.check()
        if not self._previous:
            return fn(*args, **kwargs)
        if self._jobs is None:
            self._jobs = queue.SimpleQueue()
            self._helper = threading.Thread(target=_make_calls, args=(self._jobs,),
                                            name="gamma-runtime-call", daemon=True)
            self._helper.start()
        outcome = Outcome()
        self._jobs.put((outcome, fn, args, kwargs))
        try:
            while not outcome.wait(self.STEP):
                if self.signum is not None:
                    raise Interrupted(self.signum)
        except BaseException:
            # Interrupted, or what another signal's handler raised while waiting
            # (SIGALRM's, a test's timeout): the call is abandoned, its thread
            # ends after it, the next call gets a new one
            if not outcome.done():
                self.busy, self.abandoned = True, outcome
                self._jobs.put(None)
                # (joined at the interpreter's exit: a thread that comes back from the
                # runtime while the interpreter finalizes aborts the process)
                background.join_at_exit(self._helper)
                self._jobs = self._helper = None
            raise
        value = outcome.result()
        self.check()
        return value


def _make_calls(jobs: queue.SimpleQueue) -> None:
    """The helper thread: the calls of ``jobs`` in order, until a None."""
    while True:
        job = jobs.get()
        if job is None:
            return
        outcome, fn, args, kwargs = job
        value, error = None, None
        try:
            value = fn(*args, **kwargs)
        except BaseException as err:  # noqa: BLE001 - re-raised on the main thread
            error = err
        del job, fn, args, kwargs       # held no longer than the call
        outcome.settle(value, error)
        del outcome, value, error       # nor its value while the next is awaited
