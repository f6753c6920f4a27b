"""gammac run imports what its outputs need while the runtime builds the
simulation (gamma/driver/running/warmup.py): by the time the first iteration is
traced, Pillow's drawing is imported (Pillow's image plugins only for a run
that saves an appearance sequence), and the outputs are those of a run
without the warm-up.  numpy.ma is imported by nothing: the scale's
percentile is worked out without np.percentile, which imported it (~15 ms of
CPU).  tqdm is imported by nothing: its import alone
cost ~50 ms of a run's CPU (driver/outputs/progress.py draws the bar)."""

import subprocess
import sys
import textwrap

from conftest import ROOT

SCRIPT = textwrap.dedent("""
    import sys, tempfile, threading
    from gamma import compile
    from gamma.driver.running import runner
    from gamma.driver.running.events import CallbackWriter, IterationTraced

    warm = sys.argv[1] == "warm"
    seen = {}
    def first_trace(event):
        if not seen:
            for t in threading.enumerate():
                if t.name == "gamma-warmup":
                    t.join()
            seen.update({m: m in sys.modules
                         for m in ("PIL.ImageDraw", "PIL.ImageFont", "PIL.GifImagePlugin", "tqdm", "numpy.ma")})
    effect = compile(sys.argv[2])
    out = tempfile.mkdtemp()
    opts = runner.RunOptions(scene=sys.argv[3], out=out, iterations=2, surfels=2000, tons=5000,
                             width=32, height=32, progress=warm)
    runner.run(effect, opts, writers=[CallbackWriter(first_trace, events=(IterationTraced,))], standard=warm)
    print(seen)
""")


def imported(kind: str, effect: str, mesh) -> str:
    r = subprocess.run([sys.executable, "-c", SCRIPT, kind, ROOT / "examples" / effect, mesh],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    return r.stdout.strip()


def test_the_outputs_modules_are_imported_during_the_setup(box_obj):
    # false-colour renders: Pillow's drawing and its font, not its image plugins
    assert imported("warm", "patina.gamma", box_obj) == (
        "{'PIL.ImageDraw': True, 'PIL.ImageFont': True, 'PIL.GifImagePlugin': False, 'tqdm': False, "
        "'numpy.ma': False}")
    # an appearance run saves its sequence as a GIF with Pillow: the plugins too
    assert imported("warm", "leak-stain.gamma", box_obj) == (
        "{'PIL.ImageDraw': True, 'PIL.ImageFont': True, 'PIL.GifImagePlugin': True, 'tqdm': False, "
        "'numpy.ma': False}")
    # without the standard outputs (the Python API) nothing is warmed up
    assert imported("cold", "patina.gamma", box_obj) == (
        "{'PIL.ImageDraw': False, 'PIL.ImageFont': False, 'PIL.GifImagePlugin': False, 'tqdm': False, "
        "'numpy.ma': False}")
