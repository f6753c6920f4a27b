"""gamma.driver.running.interrupt: Interruptions.call runs a run's calls on
the calling thread with their values and errors; a signal cancels the run's
token, a runtime pass given that token stops within a chunk, and the call
raises Interrupted.  Handlers and the wakeup fd are put back afterwards and
no thread is left.  (tests/test_run_faults.py signals whole ``gammac run``
processes.)"""

import os
import signal
import threading
import time

import pytest

from conftest import ROOT
from gamma.backends.jit import JitKernels
from gamma.driver.running.common import runtime_module
from gamma.driver.running.interrupt import Interrupted, Interruptions
from gamma.driver.running.runner import RunOptions, build_config
from gamma.driver.running.scene import load_scene
from gamma.frontend.checker import check
from gamma.frontend.parser import parse


def test_calls_run_on_the_calling_thread_with_their_values_and_errors():
    with Interruptions() as stop:
        assert stop.call(threading.get_ident) == threading.get_ident()
        assert stop.call(lambda a, b=1: a * b, 6, b=7) == 42
        with pytest.raises(ZeroDivisionError):
            stop.call(lambda: 1 / 0)
        assert not stop.token.cancelled
        stop.check()


@pytest.fixture(scope="module")
def busy():
    """A simulation whose traces take a while (200k γ-tons each), and the
    kernels it needs alive."""
    rt = runtime_module()
    eff = check(parse((ROOT / "examples" / "patina.gamma").read_text(), str(ROOT / "examples" / "x.gamma")))
    scene = load_scene(rt, str(ROOT / "examples" / "scenes" / "stanford-bunny.obj"), eff, [], None)
    kernels = JitKernels(eff)
    cfg = build_config(rt, eff, kernels, RunOptions(scene="b", out="", surfels=5000, tons=200_000, threads=2),
                       scene.bounds, scene.down)
    cfg.triangle_surface = scene.triangle_surface
    return rt.Simulation(scene.mesh, cfg), kernels


def test_a_signal_stops_a_runtime_pass_given_the_token_and_the_call_raises_interrupted(busy):
    sim, _ = busy
    before = signal.getsignal(signal.SIGINT)    # (SIG_IGN in a job a shell started in the background)
    watchers = {t for t in threading.enumerate() if t.name == "gamma-signal-watcher"}
    with Interruptions() as stop:
        threading.Timer(0.2, os.kill, (os.getpid(), signal.SIGINT)).start()
        started = time.perf_counter()
        with pytest.raises(Interrupted) as raised:
            stop.call(lambda: [sim.trace(i, cancel=stop.token) for i in range(1000)])
        assert time.perf_counter() - started < 0.2 + 0.5
        assert raised.value.status == 130 and raised.value.name == "SIGINT"
        assert stop.token.cancelled
        with pytest.raises(Interrupted):
            stop.check()
        with pytest.raises(Interrupted):
            stop.call(lambda: "after the signal")
    assert signal.getsignal(signal.SIGINT) is before      # the handlers are put back
    assert signal.set_wakeup_fd(-1) == -1                  # and the wakeup fd
    assert {t for t in threading.enumerate() if t.name == "gamma-signal-watcher"} == watchers


def test_sigterm_gives_143():
    with Interruptions() as stop:
        os.kill(os.getpid(), signal.SIGTERM)
        deadline = time.monotonic() + 5
        while not stop.token.cancelled and time.monotonic() < deadline:
            time.sleep(0.01)
        with pytest.raises(Interrupted) as raised:
            stop.check()
    assert raised.value.status == 143


def test_a_token_cancelled_by_its_owner_is_not_an_interruption(busy):
    # (the viewer cancels a run an edit has superseded): Cancelled passes through
    sim, _ = busy
    rt = runtime_module()
    with Interruptions() as stop:
        stop.token.cancel()
        with pytest.raises(rt.Cancelled):
            stop.call(sim.trace, 1, cancel=stop.token)
        assert stop.signum is None


def test_off_the_main_thread_no_handler_is_installed_and_the_token_still_works():
    seen = {}

    def body():
        with Interruptions() as stop:
            seen["handler"] = signal.getsignal(signal.SIGINT)
            stop.token.cancel()
            seen["cancelled"] = stop.token.cancelled

    before = signal.getsignal(signal.SIGINT)
    t = threading.Thread(target=body)
    t.start()
    t.join()
    assert seen == {"handler": before, "cancelled": True}
