"""Faults and interruption of `gammac run` (issue 13): --resume continues
bit-identically, SIGINT/SIGTERM stop promptly with SPEC's status and a
consistent folder, a failed rerun keeps the earlier results, a killed run's
temporary files are cleaned, one run per folder, a closed pipe does not stop
a run, NaN from an appearance program is reported with its position."""

import json
import os
import signal
import subprocess
import sys
import textwrap
import threading
import time

import pytest

from conftest import ROOT, run_gammac
from gamma.driver.outputs.outputs import read_ply

PATINA = ROOT / "examples" / "patina.gamma"
BUNNY = ROOT / "examples" / "scenes" / "stanford-bunny.obj"


def args(out, iterations, *extra, tons=3000):
    return [PATINA, "--scene", BUNNY, "--surfels", 500, "--tons", tons, "--iterations", iterations,
            "--size", 16, "--quiet", "--out", out, *extra]


def summary(out):
    return json.loads((out / "summary.json").read_text())


def maps(out):
    return sorted(p.name for p in (out / "maps").glob("iter_*.ply"))


def test_summary_says_requested_and_completed(tmp_path):
    assert run_gammac("run", *args(tmp_path / "o", 2)).returncode == 0
    s = summary(tmp_path / "o")
    assert s["requested_iterations"] == 2 and s["completed"] is True and len(s["iterations"]) == 2


def test_resume_is_bit_identical_to_an_uninterrupted_run(tmp_path):
    whole, part = tmp_path / "whole", tmp_path / "part"
    assert run_gammac("run", *args(whole, 4)).returncode == 0
    assert run_gammac("run", *args(part, 2)).returncode == 0
    r = run_gammac("run", *args(part, 4, "--resume"))
    assert r.returncode == 0, r.stderr
    assert maps(part) == maps(whole) == [f"iter_000{i}.ply" for i in range(1, 5)]
    for name in maps(whole):
        assert (part / "maps" / name).read_bytes() == (whole / "maps" / name).read_bytes(), name
    for name in ("iter_0001.png", "iter_0004.png"):    # one colour scale over all four
        assert (part / "renders" / name).read_bytes() == (whole / "renders" / name).read_bytes()
    s, w = summary(part), summary(whole)
    assert s["completed"] is True and s["resumed_at"] == 3
    assert [i["settled"] for i in s["iterations"]] == [i["settled"] for i in w["iterations"]]
    assert s["ranges"] == w["ranges"]                  # over all four


def test_resume_refuses_another_run(tmp_path):
    assert run_gammac("run", *args(tmp_path / "o", 1)).returncode == 0
    r = run_gammac("run", *args(tmp_path / "o", 2, "--resume", "--seed", "7"))
    assert r.returncode == 1 and "another effect, scene or options" in r.stderr
    assert maps(tmp_path / "o") == ["iter_0001.ply"]
    r = run_gammac("run", *args(tmp_path / "o", 1, "--resume"))
    assert r.returncode == 1 and "already holds 1 iterations" in r.stderr
    r = run_gammac("run", *args(tmp_path / "none", 2, "--resume"))
    assert r.returncode == 1 and "no run to resume" in r.stderr


def signalled(cmd, sig, ready):
    """Runs ``cmd``, sends it ``sig`` once ``ready(proc)`` has returned, and
    returns (the process, its stderr, the seconds it took to end after the
    signal)."""
    proc = subprocess.Popen(cmd, stderr=subprocess.PIPE, text=True)
    try:
        ready(proc)
        proc.send_signal(sig)
        sent = time.monotonic()
        proc.wait(timeout=60)
        waited = time.monotonic() - sent
    finally:
        if proc.poll() is None:
            proc.kill()
    return proc, proc.stderr.read(), waited


@pytest.mark.parametrize("sig,status", [(signal.SIGINT, 130), (signal.SIGTERM, 143)])
def test_signal_stops_promptly_with_a_consistent_folder(tmp_path, sig, status):
    out = tmp_path / "o"

    def in_the_second_iteration(proc):
        deadline = time.monotonic() + 300
        while not (out / "maps" / "iter_0001.ply").exists() and time.monotonic() < deadline:
            assert proc.poll() is None, proc.stderr.read()
            time.sleep(0.05)
        time.sleep(0.2)                          # into the next tracing pass

    proc, err, waited = signalled([sys.executable, "-m", "gamma.cli", "run", *map(str, args(out, 50, tons=400_000))],
                                  sig, in_the_second_iteration)
    assert proc.returncode == status, err
    assert waited < 10, waited                   # ~0.3 s unloaded; slack for a busy machine
    assert f"interrupted by {signal.Signals(sig).name}" in err and "Traceback" not in err
    s = summary(out)
    assert s["completed"] is False and s["requested_iterations"] == 50
    done = len(s["iterations"])
    assert done >= 1 and maps(out) == [f"iter_{i:04d}.ply" for i in range(1, done + 1)]
    for name in maps(out):                       # complete maps only
        assert len(read_ply(out / "maps" / name)["x"]) == s["surfels"]
    assert not list(out.rglob(".*"))           # no temporary file, no lock, nothing set aside


def test_a_signal_stops_gammac_export_while_it_bakes(tmp_path):
    """gammac export hands the command's cancel token to the set-up and the
    bakes: SIGINT in a long bake ends it promptly with 130, no traceback and
    no temporary file."""
    out = tmp_path / "o"
    assert run_gammac("run", *args(out, 1)).returncode == 0

    def in_the_bake(proc):
        time.sleep(EXPORT_SIGNAL_AFTER)             # past the start-up and the set-up, into the bake
        assert proc.poll() is None, "the export ended before the signal: make it longer"

    proc, err, waited = signalled([sys.executable, "-m", "gamma.cli", "export", str(out), "--bake-size", "8192"],
                                  signal.SIGINT, in_the_bake)
    assert proc.returncode == 130, err
    assert waited < 10, waited                   # a bake's block of texels; slack for a busy machine
    assert "export interrupted by SIGINT" in err and "Traceback" not in err
    assert not list(out.rglob(".*"))


#: Seconds from the start of `gammac export --bake-size 8192` to its signal.
EXPORT_SIGNAL_AFTER = 3.0


def test_a_signal_during_the_setup_stops_it_and_keeps_the_earlier_results(tmp_path, monkeypatch):
    # (it was a traceback: Interrupted escaped from the setup, the folder's lock left behind)
    from gamma.driver.running import runner
    from gamma.driver.running.runner import RunInterrupted, RunOptions, run
    from gamma.frontend.checker import load

    out = tmp_path / "o"
    assert run_gammac("run", *args(out, 1)).returncode == 0
    before = {p.relative_to(out): p.read_bytes() for p in out.rglob("*") if p.is_file()}
    setup = runner._simulation

    def signalled_setup(*a, **k):
        os.kill(os.getpid(), signal.SIGINT)
        time.sleep(0.2)                         # noticed before the set-up's first phase
        return setup(*a, **k)

    monkeypatch.setattr(runner, "_simulation", signalled_setup)
    opts = RunOptions(scene=str(BUNNY), out=str(out), surfels=500, tons=3000, iterations=1,
                      width=16, height=16, progress=False)
    with pytest.raises(RunInterrupted) as raised:
        run(load(str(PATINA)), opts)
    stop = raised.value
    assert stop.status == 130 and "before the first iteration" in str(stop)
    assert not [t for t in threading.enumerate() if t.name.startswith("gamma-")]
    after = {p.relative_to(out): p.read_bytes() for p in out.rglob("*") if p.is_file()}
    assert after == before


# gamma.run interrupted while it traces, in a script that then ends through the
# interpreter's exit: the trace stops at its next chunk and nothing runs on
# when the interpreter finalizes (before cancellation was cooperative, an
# abandoned trace came back into a finalizing interpreter: "terminate called
# without an active exception" and SIGABRT, or nanobind's report of a leaked
# Simulation).
TRACE_INTERRUPTED = textwrap.dedent("""
    import os, signal, sys, threading, time
    import gamma
    from gamma.driver.running import runner
    from gamma.driver.running.runner import RunInterrupted
    assert gamma.RunInterrupted is RunInterrupted
    second_trace = threading.Event()
    trace = runner.Run.trace
    def trace_and_tell(self, it):
        if it == 2:
            second_trace.set()
        return trace(self, it)
    runner.Run.trace = trace_and_tell
    def signal_in_the_second_trace():
        if second_trace.wait(120):
            time.sleep(0.05)
            os.kill(os.getpid(), signal.SIGINT)
    threading.Thread(target=signal_in_the_second_trace, daemon=True).start()
    effect = gamma.compile(sys.argv[1])
    try:
        gamma.run(effect, sys.argv[2], iterations=50, surfels=3000, tons=4_000_000, threads=2)
    except RunInterrupted as stop:
        print("interrupted", stop.status, flush=True)
""")


def test_a_script_whose_run_was_interrupted_while_tracing_ends_cleanly():
    r = subprocess.run([sys.executable, "-c", TRACE_INTERRUPTED, str(PATINA), str(BUNNY)],
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    assert r.stdout.split() == ["interrupted", "130"]
    assert "leaked" not in r.stderr and "terminate" not in r.stderr


def test_an_update_that_ends_after_the_signal_leaves_nothing_of_its_iteration_in_the_summary(tmp_path,
                                                                                            monkeypatch):
    # the update is waited for (the simulations are left alone): its value
    # ranges and non-finite counts go with its iteration, in a fresh run and in
    # a resumed one (which carries the earlier iterations' ranges)
    from gamma.driver.running import runner
    from gamma.driver.running.runner import RunInterrupted, RunOptions, run
    from gamma.frontend.checker import load

    (tmp_path / "nan.gamma").write_text(
        "ton T { motion straight = 0.5 carry a = 1 }\nsurface S { property p = 0, q = 0 }\n"
        "source s = environment(sphere) emits T count 3000\n"
        "on settle(t: T, s: S) {\n    s.p += t.a\n    s.q += t.a / (s.p - s.p)\n}\n")
    effect = load(str(tmp_path / "nan.gamma"))

    def opts(out, iterations, resume=False):
        return RunOptions(scene=str(BUNNY), out=str(tmp_path / out), surfels=500, iterations=iterations,
                          width=16, height=16, progress=False, resume=resume)

    for name, iterations in (("one", 1), ("two", 2)):
        run(effect, opts(name, iterations))
    update, signal_in = runner.Run.update, []

    def signalled_update(self, it, traced):
        if it in signal_in:
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(0.2)                     # noticed while this update runs
        return update(self, it, traced)

    monkeypatch.setattr(runner.Run, "update", signalled_update)
    for iterations, resume, dropped, like in ((3, False, 2, "one"), (4, True, 3, "two")):
        signal_in[:] = [dropped]
        with pytest.raises(RunInterrupted) as raised:
            run(effect, opts("cut", iterations, resume))
        assert f"during iteration {dropped}" in str(raised.value)
        cut, reference = summary(tmp_path / "cut"), summary(tmp_path / like)
        assert len(cut["iterations"]) == dropped - 1 and cut["completed"] is False
        assert cut["nonfinite"][0]["count"] > 0
        assert cut["ranges"] == reference["ranges"] and cut["nonfinite"] == reference["nonfinite"]


def test_a_cancelled_token_stops_each_long_pass_and_leaves_the_surfels_as_they_were():
    import numpy as np

    import gamma
    from gamma.driver.running.common import runtime_module

    rt = runtime_module()
    result = gamma.run(gamma.compile(PATINA), BUNNY, iterations=1, surfels=500, tons=2000)
    sim, stopped = result.session.sim, rt.CancelToken()
    stopped.cancel()
    rows = np.asarray(sim.rows()).copy()
    for name, call in (("trace", lambda: sim.trace(2, cancel=stopped)),
                       ("update", lambda: sim.update(2, cancel=stopped)),
                       ("render", lambda: sim.render(np.zeros(sim.num_surfels, np.float32), (0, 0, 3), (0, 0, 0),
                                                     (0, 1, 0), 40.0, 64, 64, 2, cancel=stopped)),
                       ("view", lambda: sim.false_colour_view((0, 0, 3), (0, 0, 0), (0, 1, 0), 40.0, 64, 64, 2,
                                                              cancel=stopped))):
        with pytest.raises(rt.Cancelled, match="^cancelled: "):
            call()
        assert np.array_equal(np.asarray(sim.rows()), rows), name
    sim.trace(2, cancel=rt.CancelToken())         # a token nobody cancelled, or none, runs whole
    sim.update(2)
    assert not np.array_equal(np.asarray(sim.rows()), rows)


def test_a_signal_while_gammac_watch_computes_a_result_stops_it_without_a_traceback(tmp_path):
    # (it was RunInterrupted's traceback, exit 1, naming the viewer's scratch folder)
    cmd = [sys.executable, "-m", "gamma.cli", "watch", str(PATINA), "--scene", str(BUNNY), "--surfels", "4000",
           "--tons", "2000000", "--iterations", "3", "--port", "0", "--threads", "2"]
    proc = subprocess.Popen(cmd, stderr=subprocess.PIPE, text=True, env=dict(os.environ, PYTHONUNBUFFERED="1"))
    log = []
    try:
        for line in proc.stderr:                 # the preview's result: the final run starts now
            log.append(line)
            if "preview result" in line:
                time.sleep(0.3)
                proc.send_signal(signal.SIGINT)
                break
        log.extend(proc.stderr)
        proc.wait(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    err = "".join(log)
    assert proc.returncode == 130, err
    # (by SIGINT: said only where the run is stopped, not by the handler of a ^C between runs)
    assert "preview result" in err and err.rstrip().endswith("gammac: interrupted by SIGINT")
    assert "Traceback" not in err


def test_failed_rerun_keeps_the_earlier_results(tmp_path):
    from gamma.driver.running.events import CallbackWriter, IterationUpdated
    from gamma.driver.running.runner import RunOptions, run
    from gamma.frontend.checker import load

    out = tmp_path / "o"
    assert run_gammac("run", *args(out, 2)).returncode == 0
    before = {p.relative_to(out): p.read_bytes() for p in out.rglob("*") if p.is_file()}

    def fail(event):
        if event.iteration == 1:
            raise RuntimeError("disk on fire")

    opts = RunOptions(scene=str(BUNNY), out=str(out), surfels=300, tons=100, iterations=3,
                      width=16, height=16, progress=False)
    with pytest.raises(RuntimeError, match="disk on fire"):
        run(load(str(PATINA)), opts, writers=[CallbackWriter(fail, events=(IterationUpdated,))])
    after = {p.relative_to(out): p.read_bytes() for p in out.rglob("*") if p.is_file()}
    assert after == before


def test_killed_run_leaves_nothing_stale(tmp_path):
    out = tmp_path / "o"
    assert run_gammac("run", *args(out, 1)).returncode == 0
    stale = [out / "maps" / ".iter_0001.ply.k2j3h4", out / ".summary.json.x7y8z9",
             out / "renders" / ".sequence.abc.mp4"]
    for path in stale:
        path.write_bytes(b"half")
    (out / ".previous-run" / "maps").mkdir(parents=True)
    (out / ".previous-run" / "maps" / "iter_0009.ply").write_bytes(b"old")
    assert run_gammac("run", *args(out, 1)).returncode == 0
    assert not any(p.exists() for p in stale)
    assert not (out / ".previous-run").exists()
    assert maps(out) == ["iter_0001.ply"]


def test_one_run_per_folder(tmp_path):
    from gamma.driver.running.folder import OutputLock

    out = tmp_path / "o"
    out.mkdir()
    with OutputLock(out):
        r = run_gammac("run", *args(out, 1))
    assert r.returncode == 1 and "another gammac run is writing to" in r.stderr
    assert run_gammac("run", *args(out, 1)).returncode == 0


def test_closed_pipe_does_not_stop_the_run(tmp_path):
    out = tmp_path / "o"
    command = " ".join(f"'{a}'" for a in [sys.executable, "-m", "gamma.cli", "run",
                                            *[str(a) for a in args(out, 3) if a != "--quiet"]])
    # progress lines on stderr into a reader that leaves after the first byte
    r = subprocess.run(["bash", "-c", f"set -o pipefail; {command} 2>&1 | head -c 1; "
                                      "echo; echo status=${PIPESTATUS[0]}"],
                       capture_output=True, text=True, timeout=600)
    assert "status=0" in r.stdout, r.stdout + r.stderr
    s = summary(out)
    assert s["completed"] is True and len(s["iterations"]) == 3


def test_appearance_nan_is_reported_with_its_position(tmp_path):
    effect = tmp_path / "e.gamma"
    effect.write_text(PATINA.read_text() + "\nappearance(s: Copper) {\n"
                      "    color = rgb(1, 1, 1) * log(s.patina - 1)\n}\n")
    r = run_gammac("run", effect, "--scene", BUNNY, "--surfels", 300, "--tons", 300,
                   "--iterations", 1, "--size", 16, "--samples", 1, "--ao", 0, "--quiet",
                   "--out", tmp_path / "o")
    assert r.returncode == 0, r.stderr
    line = next(l for l in r.stderr.splitlines() if "NaN or infinity" in l)
    assert "e.gamma:" in line and "appearance(Copper)" in line
    entries = summary(tmp_path / "o")["nonfinite"]
    assert any(e["rule"] == "appearance(Copper)" and e["count"] > 0 for e in entries), entries
