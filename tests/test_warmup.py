"""gammac run imports what its outputs need while the runtime builds the
simulation (gamma/driver/warmup.py): by the time the first iteration is
traced, Pillow's PNG plugin, tqdm and numpy.ma are imported, and the outputs
are those of a run without the warm-up."""

import subprocess
import sys
import textwrap

from conftest import ROOT

SCRIPT = textwrap.dedent("""
    import sys, tempfile, threading
    from gamma import compile
    from gamma.driver import runner
    from gamma.driver.events import CallbackWriter, IterationTraced

    warm = sys.argv[1] == "warm"
    seen = {}
    def first_trace(event):
        if not seen:
            for t in threading.enumerate():
                if t.name == "gamma-warmup":
                    t.join()
            seen.update({m: m in sys.modules for m in ("PIL.PngImagePlugin", "tqdm", "numpy.ma")})
    effect = compile(sys.argv[2])
    out = tempfile.mkdtemp()
    opts = runner.RunOptions(scene=sys.argv[3], out=out, iterations=2, surfels=2000, tons=5000,
                             width=32, height=32, progress=warm)
    runner.run(effect, opts, writers=[CallbackWriter(first_trace, events=(IterationTraced,))], standard=warm)
    print(seen)
""")


def test_the_outputs_modules_are_imported_during_the_setup(box_obj):
    r = subprocess.run([sys.executable, "-c", SCRIPT, "warm", ROOT / "examples" / "patina.gamma", box_obj],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == "{'PIL.PngImagePlugin': True, 'tqdm': True, 'numpy.ma': True}"
    # without the standard outputs (the Python API) nothing is warmed up
    r = subprocess.run([sys.executable, "-c", SCRIPT, "cold", ROOT / "examples" / "patina.gamma", box_obj],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == "{'PIL.PngImagePlugin': False, 'tqdm': False, 'numpy.ma': False}"
