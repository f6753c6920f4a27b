"""Benchmark: `gammac watch` on the Stanford bunny at 100,000 surfels with
examples/patina.gamma (4M γ-tons per iteration, 10 iterations): the time from
saving an edit to the preview result being published to the page, for each
preview fraction the page offers (goal, issue 12: within 1 s), against the
time to the full-quality result without a preview (the baseline measured in
the same run).

    .venv/bin/python bench/bench_watch.py [--record]
"""

from __future__ import annotations

import argparse
import shutil
import tempfile
import threading
import time
from pathlib import Path

from report import ROOT, SCENE, cpu_name, report
from gamma.driver.running.runner import RunOptions
from gamma.viewer.server import ViewerState
from gamma.viewer.watch import Watcher



def after_save(folder: Path, preview: float, threads: int) -> tuple[float, float]:
    """(seconds to the preview, seconds to the full result) after a save."""
    effect = folder / "patina.gamma"
    state = ViewerState(str(effect), str(SCENE), preview)
    stop = threading.Event()
    watcher = Watcher(str(effect), {}, RunOptions(scene=str(SCENE), out="", surfels=100_000, threads=threads),
                      state, stop, log=lambda text: None)
    thread = threading.Thread(target=watcher.run_forever)
    thread.start()

    def wait(condition):
        while not condition(state.snapshot()):
            time.sleep(0.002)
        return time.perf_counter()

    try:
        wait(lambda s: s["generation"] == 1 and s["iterations"] > 0)      # the first result (start-up)
        text = effect.read_text()
        saved = time.perf_counter()
        effect.write_text(text.replace("0.05 * t.patina", "0.06 * t.patina"))
        first = wait(lambda s: s["generation"] == 2 and s["iterations"] > 0)
        full = wait(lambda s: s["generation"] == 2 and s["status"] == "ready") if preview == 1.0 else first
    finally:
        stop.set()
        thread.join()
    return first - saved, full - saved


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--record", action="store_true")
    ap.add_argument("--threads", type=int, default=2)
    args = ap.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        shutil.copy(ROOT / "examples" / "patina.gamma", tmp)
        _, baseline = after_save(Path(tmp), 1.0, args.threads)       # no preview: the full run
        for preview in (1 / 64, 1 / 8):
            first, _ = after_save(Path(tmp), preview, args.threads)
            rows.append(f"| {preview:.4g} | {first:.2f} | {baseline:.2f} | {first / baseline:.3f} |")
    report("gammac watch: save to result on the bunny (issue 12)",
           f"{cpu_name()}, {args.threads} threads; bunny, 100,000 surfels, patina (4M γ-tons x 10 iterations)",
           "| preview fraction | save → preview s | save → full result s (no preview) | ratio |\n|---|---|---|---|",
           rows, args.record)


if __name__ == "__main__":
    main()
