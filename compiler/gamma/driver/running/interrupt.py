"""SIGINT and SIGTERM during a run: noticed within a fraction of a second,
even while the runtime is busy for minutes in one call.

Python runs a signal handler only on the main thread, between bytecodes, so
a long C++ call (a trace, the set-up, a render) would hold it off until it
returns.  Instead the runtime cancels cooperatively: every long pass takes
the run's ``CancelToken`` (``cancel=``) and checks it between chunks of its
work (gamma/cancel.h).  While ``Interruptions`` is active on the main
thread, the interpreter's C-level handler writes each signal's number to a
socket (``signal.set_wakeup_fd``) that a watcher thread reads; the watcher
cancels the token at once, the pass raises ``Cancelled`` within a chunk's
time, and ``call`` turns that into ``Interrupted``.  Calls run on the
thread that makes them: none is left running, and a command ends through
the interpreter's normal exit.
"""

from __future__ import annotations

import signal
import socket
import threading

from .common import runtime_module

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
    land) while it is active, cancel ``token``, and make ``check``/``call``
    raise ``Interrupted``.  Outside the main thread (a program running
    ``run`` from a thread) signals cannot be caught; the token still stops
    the passes it is given when someone else cancels it (the viewer)."""

    def __init__(self):
        self.signum: int | None = None
        self.token = runtime_module().CancelToken()
        self._previous: dict = {}
        self._previous_wakeup: int | None = None
        self._wakeup: socket.socket | None = None     # written by the C-level handler
        self._watcher: threading.Thread | None = None

    def __enter__(self) -> "Interruptions":
        if threading.current_thread() is not threading.main_thread():
            return self
        reader, writer = socket.socketpair()
        writer.setblocking(False)      # (set_wakeup_fd requires it)
        self._previous_wakeup = signal.set_wakeup_fd(writer.fileno(), warn_on_full_buffer=False)
        self._wakeup = writer
        for sig in SIGNAL_NAMES:
            self._previous[sig] = signal.signal(sig, self._record)
        self._watcher = threading.Thread(target=self._watch, args=(reader,), name="gamma-signal-watcher",
                                         daemon=True)
        self._watcher.start()
        return self

    def __exit__(self, *exc) -> None:
        if self._wakeup is None:
            return
        for sig, handler in self._previous.items():
            signal.signal(sig, handler)
        self._previous.clear()
        signal.set_wakeup_fd(self._previous_wakeup)
        self._wakeup.close()           # the watcher reads the end of its stream and ends
        self._watcher.join()
        self._wakeup = self._watcher = None

    def _watch(self, reader: socket.socket) -> None:
        with reader:
            while True:
                try:
                    numbers = reader.recv(64)
                except OSError:
                    return
                if not numbers:
                    return
                for signum in numbers:
                    if signum in SIGNAL_NAMES:
                        self._note(signum)

    def _record(self, signum, frame) -> None:
        self._note(signum)

    def _note(self, signum: int) -> None:
        if self.signum is None:
            self.signum = signum
        self.token.cancel()

    def check(self) -> None:
        if self.signum is not None:
            raise Interrupted(self.signum)

    def call(self, fn, *args, **kwargs):
        """``fn(*args, **kwargs)``; ``Interrupted`` if a signal came before,
        during (the pass it makes was given ``token`` and stopped) or after it."""
        self.check()
        try:
            value = fn(*args, **kwargs)
        except runtime_module().Cancelled:
            if self.signum is None:
                raise           # cancelled by its owner (the viewer), not by a signal
            raise Interrupted(self.signum) from None
        self.check()
        return value
