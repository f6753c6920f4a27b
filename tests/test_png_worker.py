"""gammac run's PNG worker process (gamma/driver/png_worker.py): the pictures
it encodes are byte for byte those encoded here, a worker that fails or dies
only means the picture is encoded here, and it leaves with its parent."""

import subprocess
import sys
import textwrap

SCRIPT = textwrap.dedent("""
    import os, signal, sys, tempfile, time
    from pathlib import Path
    from gamma.driver import png_worker
    png_worker.start()                       # no other thread yet: it forks
    import numpy as np
    worker = png_worker.worker()
    assert worker is not None, "no worker"
    time.sleep(0.5)
    with open(f"/proc/{worker.pid}/maps") as maps:   # the worker needs Pillow, not numpy
        assert "_multiarray_umath" not in maps.read()
    from gamma.driver.outputs import FalseColourCanvas
    from gamma.driver.writers import _write_false_colour_views

    class View:                              # FalseColourView's picture(), from fixed pixels
        def __init__(self, seed):
            self.rng = np.random.default_rng(seed)
        def picture(self, values, vmin, vmax, background, threads):
            return (np.clip(values[:32 * 40].reshape(32, 40, 1) * 255, 0, 255)
                    * np.ones((1, 1, 3))).astype(np.uint8)

    args = (40, 32, -0.5, 2.0, "rust")
    canvas = FalseColourCanvas(*args)
    rng = np.random.default_rng(7)
    values = [rng.random(32 * 40).astype(np.float32) for _ in range(5)]
    view = View(1)
    here = [canvas.png(None, None, f"rust, iteration {i}",
                       picture=view.picture(v, -0.5, 2.0, canvas.background, 1)) for i, v in enumerate(values)]
    # the worker's bytes are ours
    for i, v in enumerate(values):
        worker.send(canvas.frame, canvas.height, f"rust, iteration {i}",
                    view.picture(v, -0.5, 2.0, canvas.background, 1))
        assert worker.receive() == here[i], i
    folder = Path(tempfile.mkdtemp())
    items = [(folder / f"a{i}.png", f"rust, iteration {i}", v) for i, v in enumerate(values)]
    for k in range(0, 5, 2):
        _write_false_colour_views(items[k:k + 2], canvas, view, -0.5, 2.0, 1, worker)
    assert [p.read_bytes() for p, _, _ in items] == here
    # a worker that died: everything encoded here, same files
    os.kill(worker.pid, signal.SIGKILL)
    os.waitpid(worker.pid, 0)
    items = [(folder / f"b{i}.png", f"rust, iteration {i}", v) for i, v in enumerate(values)]
    for k in range(0, 5, 2):
        _write_false_colour_views(items[k:k + 2], canvas, view, -0.5, 2.0, 1, worker)
    assert [p.read_bytes() for p, _, _ in items] == here
    assert png_worker.worker() is None       # known dead
    print("ok")
""")

LEAVES = textwrap.dedent("""
    import os, signal, time
    from gamma.driver import png_worker
    png_worker.start()
    pid = png_worker.worker().pid
    os.kill(pid, signal.SIGINT)              # ignored: the run handles Ctrl-C
    time.sleep(0.3)
    assert os.waitpid(pid, os.WNOHANG) == (0, 0), "the worker died of SIGINT"
    png_worker.stop()                        # the pipe closes: the worker leaves
    for _ in range(200):
        done, status = os.waitpid(pid, os.WNOHANG)
        if done:
            break
        time.sleep(0.05)
    assert done == pid and os.WIFEXITED(status) and os.WEXITSTATUS(status) == 0, status
    print("ok")
""")


def run_python(code):
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)


def test_the_worker_encodes_the_same_bytes_and_a_dead_one_changes_nothing():
    r = run_python(SCRIPT)
    assert r.returncode == 0 and r.stdout.strip() == "ok", r.stderr


def test_the_worker_ignores_sigint_and_leaves_when_the_pipe_closes():
    r = run_python(LEAVES)
    assert r.returncode == 0 and r.stdout.strip() == "ok", r.stderr


def test_no_worker_is_forked_beside_other_threads():
    code = ("import threading, time\n"
            "from gamma.driver import png_worker\n"
            "t = threading.Thread(target=time.sleep, args=(0.5,)); t.start()\n"
            "png_worker.start()\n"
            "print(png_worker.worker() is None)\n")
    r = run_python(code)
    assert r.stdout.strip() == "True", r.stderr


IMPORTS_WHEN_TOLD = textwrap.dedent("""
    import time
    from gamma.driver import png_worker
    png_worker.start()
    pid = png_worker.worker().pid
    def pillow_loaded():
        with open(f"/proc/{pid}/maps") as maps:
            return "PIL/_imaging" in maps.read()
    time.sleep(0.5)
    assert not pillow_loaded(), "the worker imported Pillow for a run that may make no picture"
    png_worker.prepare()                     # the run will make pictures
    for _ in range(400):
        if pillow_loaded():
            break
        time.sleep(0.05)
    assert pillow_loaded(), "prepare() did not have the worker import Pillow"
    png_worker.stop()
    print("ok")
""")


def test_the_worker_imports_pillow_only_once_told_pictures_will_be_made():
    r = run_python(IMPORTS_WHEN_TOLD)
    assert r.returncode == 0 and r.stdout.strip() == "ok", r.stderr


def test_a_run_with_pictures_tells_the_worker_and_one_without_does_not(monkeypatch):
    from gamma.driver import png_worker, warmup

    told = []
    monkeypatch.setattr(png_worker, "prepare", lambda: told.append(True))
    warmup.prepare_outputs(progress=False, pictures=False, picture_height=512).join()
    assert told == []
    warmup.prepare_outputs(progress=False, pictures=True, picture_height=512).join()
    assert told == [True]
