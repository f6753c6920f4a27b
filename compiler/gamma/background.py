"""One call on a thread of its own, its outcome an ``Outcome``.

What ``gammac run`` does beside its main thread (the mesh read and the
surfels sampled while it starts up, the false-colour view's rays cast while
the scale is worked out, the cache files written for the next run) is one
call each, started at once.  ``concurrent.futures.ThreadPoolExecutor`` would
do, but its threads are not daemons, and the interpreter's exit would join
them before any ``atexit`` handler could stop what they run (prefetch.py
cancels a sampling nobody needs any more).  Here the thread is a daemon, and
its ``Outcome`` offers what gammac uses of a ``concurrent.futures.Future``
(``result``, ``exception``, ``done``, timeouts) without importing that
module: ``gamma.launch`` starts the mesh read (prefetch.py) before anything
else, and ``concurrent.futures``, through ``logging``, would delay it.

A daemon thread still running when the interpreter finalizes cannot come
back (it would need the GIL) and leaves whatever its frames hold behind
(nanobind then reports the runtime's objects among them as leaked at exit),
so the threads of calls are joined at exit (``atexit``), also those whose
``Outcome`` nobody holds any more.  Joined, not their outcomes waited for: a thread whose
outcome is settled still held the call's value until its frames ended, and
an exit in between left it behind (a false-colour view, seen once in CI).
"""

from __future__ import annotations

import atexit
import threading

TYPE_CHECKING = False   # (typing's import is time the read ahead would wait for)
if TYPE_CHECKING:
    from typing import Callable, Iterable

_running: set[threading.Thread] = set()   # started by start(), maybe ended since
_lock = threading.Lock()


class TimedOut(Exception):
    """``Outcome.result`` or ``exception`` waited ``timeout`` seconds in vain."""


class Outcome:
    """The outcome of one call (``start``; ``settle`` for a call made
    elsewhere), or one set at once (``Outcome.of``): ``result()`` returns
    its value or raises its error, ``exception()`` returns the error (None
    if it returned); both wait for the call, at most ``timeout`` seconds if
    given (then ``TimedOut``); ``wait`` waits without raising."""

    def __init__(self) -> None:
        self._done = threading.Event()
        self._value = None
        self._error: BaseException | None = None

    @classmethod
    def of(cls, value) -> "Outcome":
        outcome = cls()
        outcome.settle(value, None)
        return outcome

    def settle(self, value, error: BaseException | None) -> None:
        """The call returned ``value`` or raised ``error`` (once)."""
        self._value, self._error = value, error
        self._done.set()

    def done(self) -> bool:
        return self._done.is_set()

    def wait(self, timeout: float | None = None) -> bool:
        """Whether the call ended within ``timeout`` seconds (None: waits until it does)."""
        return self._done.wait(timeout)

    def exception(self, timeout: float | None = None) -> BaseException | None:
        if not self._done.wait(timeout):
            raise TimedOut(f"no outcome after {timeout} s")
        return self._error

    def result(self, timeout: float | None = None):
        error = self.exception(timeout)
        if error is not None:
            raise error
        return self._value


def start(fn: Callable, *args, name: str = "gamma-background", **kwargs) -> Outcome:
    """``fn(*args, **kwargs)`` on a new daemon thread, started now."""
    outcome = Outcome()
    call = [fn, args, kwargs]           # emptied by the thread: once settled, it holds none of them

    def work() -> None:
        fn, args, kwargs = call
        call.clear()
        value, error = None, None
        try:
            value = fn(*args, **kwargs)
        except BaseException as err:  # noqa: BLE001 - raised by result()
            error = err
        del fn, args, kwargs
        outcome.settle(value, error)

    thread = threading.Thread(target=work, name=name, daemon=True)
    try:
        thread.start()
    except BaseException as err:
        # (Python 3.12 refuses new threads while the interpreter exits): no call
        # runs, so none is joined
        outcome.settle(None, err)
        raise
    # added once started (one not started yet is not alive either, and would be
    # dropped), before whoever started it goes on: the main thread, or a thread
    # that is joined before the exit (a call's, the WriteQueue's writer), so the
    # exit cannot miss it
    global _running
    with _lock:
        _running = {t for t in _running if t.is_alive()}
        _running.add(thread)
    return outcome


def wait(outcomes: Iterable[Outcome]) -> None:
    """Wait for every one of ``outcomes`` (raising none of their errors)."""
    for outcome in outcomes:
        outcome.exception()


class Pending:
    """Calls that must end before the process does (a cache file being
    written): ``add`` each one's Outcome, and ``wait`` before leaving."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._outcomes: list[Outcome] = []

    def add(self, outcome: Outcome) -> None:
        with self._lock:
            self._outcomes.append(outcome)

    def wait(self) -> None:
        with self._lock:
            pending, self._outcomes = self._outcomes, []
        wait(pending)


@atexit.register
def _join_running() -> None:
    # until none is left: a call may start another while it is joined
    while True:
        with _lock:
            running = next((t for t in _running if t.is_alive() and t is not threading.current_thread()),
                           None)
        if running is None:
            return
        running.join()
