"""One call on a thread of its own, its outcome a ``concurrent.futures.Future``.

What ``gammac run`` does beside its main thread (the mesh read and the
surfels sampled while it starts up, the false-colour view's rays cast while
the scale is worked out, a long runtime call watched for signals) is one call
each, started at once.  ``concurrent.futures.ThreadPoolExecutor`` would do,
but its threads are not daemons: the interpreter's exit would wait for a
sampling nobody needs any more (an effect with an error), and ``cli._leave``
could not skip the interpreter's teardown.  Here the thread is a daemon; the
``Future`` is the library's (``result``, ``exception``, ``done``, timeouts).

A daemon thread still inside the runtime when the interpreter finalizes
cannot come back (it would need the GIL) and leaves its objects behind
(nanobind then reports them as leaked at exit), so the calls still running
at exit are waited for (``atexit``: only in a process that ends through the
interpreter's own exit; ``os._exit``, which ``gammac`` uses, ends them at
once).
"""

from __future__ import annotations

import atexit
import threading
from concurrent.futures import Future, wait
from typing import Callable

_running: set[Future] = set()
_lock = threading.Lock()


def start(fn: Callable, *args, name: str = "gamma-background", **kwargs) -> Future:
    """``fn(*args, **kwargs)`` on a new daemon thread, started now."""
    future: Future = Future()
    future.set_running_or_notify_cancel()
    with _lock:
        _running.add(future)

    def work() -> None:
        try:
            value = fn(*args, **kwargs)
        except BaseException as err:  # noqa: BLE001 - the Future raises it in result()
            future.set_exception(err)
        else:
            future.set_result(value)
        finally:
            with _lock:
                _running.discard(future)

    threading.Thread(target=work, name=name, daemon=True).start()
    return future


class Pending:
    """Calls that must end before the process does (a cache file being
    written): ``add`` each one's Future, and ``wait`` before leaving."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._futures: list[Future] = []

    def add(self, future: Future) -> None:
        with self._lock:
            self._futures.append(future)

    def wait(self) -> None:
        with self._lock:
            pending, self._futures = self._futures, []
        wait(pending)


@atexit.register
def _wait_for_running() -> None:
    with _lock:
        running = list(_running)
    wait(running)
