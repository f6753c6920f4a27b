"""gamma.driver.running.interrupt: Interruptions.call makes a run's calls on one helper
thread, in order, with their values and errors; a signal abandons the call
that is running (Interrupted, ``busy``) and a later call gets a new thread.
(tests/test_run_faults.py signals whole ``gammac run`` processes.)"""

import os
import signal
import threading
import time
import weakref

import pytest

from gamma.driver.running.interrupt import Interrupted, Interruptions


def test_calls_run_in_order_on_one_helper_thread_with_their_values_and_errors():
    with Interruptions() as stop:
        threads = [stop.call(lambda: threading.get_ident()) for _ in range(5)]
        assert len(set(threads)) == 1 and threads[0] != threading.get_ident()
        assert stop.call(lambda a, b=1: a * b, 6, b=7) == 42
        with pytest.raises(ZeroDivisionError):
            stop.call(lambda: 1 / 0)
        assert stop.call(threading.get_ident) == threads[0]     # an error does not end the helper
    assert not stop.busy


def test_a_signal_abandons_the_running_call_and_the_next_call_gets_a_new_thread():
    release = threading.Event()
    before = signal.getsignal(signal.SIGINT)    # (SIG_IGN in a job a shell started in the background)
    with Interruptions() as stop:
        first = stop.call(threading.get_ident)
        threading.Timer(0.1, os.kill, (os.getpid(), signal.SIGINT)).start()
        started = time.perf_counter()
        with pytest.raises(Interrupted) as raised:
            stop.call(release.wait)
        assert time.perf_counter() - started < 5 and raised.value.status == 130
        assert stop.busy
        stop.signum = None                # (a caller that carries on after an interruption)
        second = stop.call(threading.get_ident)
        assert second != first
        release.set()
    assert signal.getsignal(signal.SIGINT) is before      # the handlers are put back


class _Value:
    """A call's value (one a weak reference can follow)."""


def test_the_helper_holds_no_value_between_calls_and_has_ended_after_the_run():
    # A daemon thread still running when the interpreter finalizes leaves what
    # its frames hold behind: the helper held the last call's value (a
    # false-colour view, which nanobind then reported as leaked in CI) while it
    # waited for the next call, and the exit did not wait for it.
    with Interruptions() as stop:
        helper = stop.call(threading.current_thread)
        value = weakref.ref(stop.call(_Value))
        deadline = time.monotonic() + 5
        while value() is not None and time.monotonic() < deadline:
            time.sleep(0.01)
        assert value() is None and helper.is_alive()
    assert not helper.is_alive()


def test_an_error_a_signal_handler_raises_abandons_the_call_and_the_exit_does_not_wait_for_it():
    # (SIGALRM's handler, a test's timeout): leaving the context joins only an idle helper
    release = threading.Event()

    def alarm(signum, frame):
        raise TimeoutError("alarm")

    previous = signal.signal(signal.SIGALRM, alarm)
    try:
        started = time.perf_counter()
        with Interruptions() as stop:
            signal.setitimer(signal.ITIMER_REAL, 0.1)
            with pytest.raises(TimeoutError):
                stop.call(release.wait, 30)
            assert stop.busy
        assert time.perf_counter() - started < 20
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)
        release.set()
