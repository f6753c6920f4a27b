"""The run driver: the loop's events, writers subscribed to them, and the
ordered, bounded queue that runs writers' slow jobs behind the loop."""

import threading
import time

import numpy as np
import pytest

from conftest import ROOT
from gamma import abi
from gamma.driver import (CallbackWriter, IterationUpdated, RunError, RunFinished,
                          RunOptions, SetupDone, Writer, run)
from gamma.driver.running.events import WriteQueue
from gamma.driver.outputs.outputs import read_ply
from gamma.frontend.checker import load


def _options(scene, out, **kw):
    return RunOptions(**dict(dict(scene=str(scene), out=str(out), surfels=2000, tons=5000, iterations=3,
                                  width=64, height=64, progress=False), **kw))


def test_writers_see_every_event_in_order(tmp_path, bumpy_obj):
    seen = []
    run(load(str(ROOT / "examples" / "patina.gamma")), _options(bumpy_obj, tmp_path / "out"),
        writers=[CallbackWriter(seen.append)])
    kinds = [(type(e).__name__, getattr(e, "iteration", None)) for e in seen]
    assert kinds == [("SetupDone", None),
                     ("IterationTraced", 1), ("IterationUpdated", 1),
                     ("IterationTraced", 2), ("IterationUpdated", 2),
                     ("IterationTraced", 3), ("IterationUpdated", 3),
                     ("RunFinished", None)]
    updated = [e for e in seen if isinstance(e, IterationUpdated)]
    # the event's rows are what the map of that iteration holds
    last = read_ply(tmp_path / "out" / "maps" / "iter_0003.ply")
    assert np.array_equal(updated[-1].properties["patina"], last["patina"])
    assert updated[-1].record is seen[-1].summary["iterations"][-1]
    assert seen[-1].summary["iterations"][0]["emitted"] == seen[1].stats["emitted"] == 5000
    assert set(abi.STATISTICS) <= set(seen[1].stats)              # the runtime reports them all
    assert list(updated[0].record)[:len(abi.STATISTICS)] == list(abi.STATISTICS)


def test_a_callback_can_pick_its_events(tmp_path, bumpy_obj):
    seen = []
    run(load(str(ROOT / "examples" / "patina.gamma")), _options(bumpy_obj, tmp_path / "out"),
        writers=[CallbackWriter(seen.append, events=(SetupDone, RunFinished))])
    assert [type(e) for e in seen] == [SetupDone, RunFinished]


def test_a_writer_is_a_class_and_its_jobs_run_behind_in_order(tmp_path, bumpy_obj):
    class Sums(Writer):
        def __init__(self):
            self.written = []

        def on_iteration_updated(self, event):
            total = float(np.sum(event.properties["patina"], dtype=np.float64))
            event.run.behind(self.slow_write, event.iteration, total)

        def slow_write(self, iteration, total):
            time.sleep(0.05 if iteration == 1 else 0)   # a slow first job must not be overtaken
            assert threading.current_thread() is not threading.main_thread()
            self.written.append((iteration, total))

    writer = Sums()
    summary = run(load(str(ROOT / "examples" / "patina.gamma")), _options(bumpy_obj, tmp_path / "out"),
                  writers=[writer])
    assert [i for i, _ in writer.written] == [1, 2, 3]    # all done when run() returns
    assert [t for _, t in writer.written] == [it["property_sums"]["patina"]
                                              for it in summary["iterations"]]


def test_a_failing_job_is_a_run_error(tmp_path, bumpy_obj):
    class Full(Writer):
        def on_iteration_updated(self, event):
            event.run.behind(self.fail)

        def fail(self):
            raise OSError(28, "No space left on device")

    with pytest.raises(RunError, match="cannot write to .*No space left on device"):
        run(load(str(ROOT / "examples" / "patina.gamma")), _options(bumpy_obj, tmp_path / "out"),
            writers=[Full()])


def test_the_queue_is_bounded_ordered_and_reports_the_first_error():
    started, release = threading.Event(), threading.Event()
    done = []
    queue = WriteQueue()

    def hold():
        started.set()
        release.wait()

    with queue:
        queue(hold)
        started.wait()
        for i in range(WriteQueue.BOUND):
            queue(done.append, i)
        blocked = threading.Thread(target=queue, args=(done.append, "late"))
        blocked.start()
        blocked.join(0.2)
        assert blocked.is_alive()       # the queue is full: the producer waits
        release.set()
        blocked.join()
    assert done == list(range(WriteQueue.BOUND)) + ["late"]

    def boom():
        raise ValueError("first")

    failing = WriteQueue()
    with pytest.raises(ValueError, match="first"):
        with failing:
            failing(boom)
            failing(done.append, "skipped")
    assert "skipped" not in done


def test_the_outputs_are_written_in_order_and_the_summary_says_completed_last(tmp_path, bumpy_obj, monkeypatch):
    """Each iteration's map then summary behind the loop; after it the false-colour
    pictures (encoded together in the runtime) in iteration order; summary.json
    with ``"completed": true`` last, once every other file is whole."""
    import json

    from gamma.driver.outputs import writers

    written = []
    real = writers.atomic_write

    def recording(path, data, *args, **kwargs):
        real(path, data, *args, **kwargs)
        completed = json.loads(path.read_bytes())["completed"] if path.name == "summary.json" else None
        written.append((str(path.relative_to(tmp_path / "out")), completed))

    monkeypatch.setattr(writers, "atomic_write", recording)
    monkeypatch.setattr(writers, "write_json", lambda path, obj: recording(path, json.dumps(obj).encode()))
    run(load(str(ROOT / "examples" / "patina.gamma")), _options(bumpy_obj, tmp_path / "out"))
    per_iteration = [(f"maps/iter_{i:04d}.ply", None) for i in (1, 2, 3)]
    assert [w for w in written if w[0].startswith("maps/")] == per_iteration
    assert written[-4:] == [(f"renders/iter_{i:04d}.png", None) for i in (1, 2, 3)] + [("summary.json", True)]
    assert [c for name, c in written if name == "summary.json"] == [False, False, False, True]


def test_a_failure_encoding_the_pictures_after_the_loop_is_a_run_error_and_keeps_the_earlier_run(
        tmp_path, bumpy_obj, monkeypatch):
    from gamma.driver.outputs import outputs

    out = tmp_path / "out"
    run(load(str(ROOT / "examples" / "patina.gamma")), _options(bumpy_obj, out))
    before = {p.relative_to(out): p.read_bytes() for p in out.rglob("*") if p.is_file()}

    def full(pictures, level, threads=1):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(outputs, "encode_pngs", full)
    with pytest.raises(RunError, match="cannot write to .*No space left on device"):
        run(load(str(ROOT / "examples" / "patina.gamma")), _options(bumpy_obj, out, seed=2))
    assert {p.relative_to(out): p.read_bytes() for p in out.rglob("*") if p.is_file()} == before


def test_the_false_colour_scale_is_the_whole_runs_with_ranges_worked_out_behind_the_loop(
        tmp_path, bumpy_obj, monkeypatch):
    """The iterations' value ranges are worked out behind the loop (the last one
    after it): the pictures' scale is still the largest 99.5th percentile and
    the least value of every iteration's finite values.  The property grows
    in the first iteration and wears away after it, so the largest percentile
    is the first iteration's and the least value the last one's."""
    from gamma.driver.outputs import outputs

    scales = []

    class Recording(outputs.FalseColourCanvas):
        def __init__(self, width, height, vmin, vmax, label):
            scales.append((vmin, vmax, label))
            super().__init__(width, height, vmin, vmax, label)

    monkeypatch.setattr(outputs, "FalseColourCanvas", Recording)
    effect = tmp_path / "wear.gamma"
    effect.write_text("ton Grit {\n    motion straight = 1.0\n}\n\n"
                      "surface Stone {\n    reflectance straight = 0.5\n    property finish = 1.0\n}\n\n"
                      "source air = environment(sphere) emits Grit count 5000 strength 1\n\n"
                      "on settle(t: Grit, s: Stone) {\n    s.finish += 30 - 25 * iteration\n}\n")
    out = tmp_path / "out"
    run(load(str(effect)), _options(bumpy_obj, out, iterations=4))
    values = [read_ply(out / "maps" / f"iter_{i:04d}.ply")["finish"] for i in (1, 2, 3, 4)]
    finite = [v[np.isfinite(v)] for v in values]
    highs = [float(np.percentile(f, 99.5)) for f in finite]
    lows = [float(f.min()) for f in finite]
    assert scales == [(min(0.0, min(lows)), max(highs), "finish")]
    assert max(highs) > highs[-1] and min(lows) < min(0.0, lows[0])    # neither from one iteration alone
