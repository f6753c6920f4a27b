"""The ``gammac`` command's entry point: for ``gammac run``, the mesh's read
(and its surfels' sampling, prefetch.py) starts here, before the command
line is parsed and the command's modules are imported.

``cli.main`` starts the same read once ``argparse`` has parsed the command
line, well into the process's start: until then the second core idles, and a
first run's start-up is CPU-bound on both cores from there on.  Here the
options the read needs (``options.EARLY``) are picked out of ``sys.argv`` by hand, and
only when that is unambiguous: ``gammac run`` first, each option spelled in
full (``--scene FILE`` or ``--scene=FILE``), no abbreviation of one of them
(argparse would take ``--surf 5000`` for ``--surfels``; this scan would not
see it) and every number a plain decimal integer.  Anything else starts
nothing here, and ``cli.main`` starts the read as before.  The read is only
ever a guess: ``prefetch`` hands out its mesh only if the file is still the
one read and its surfels only if they are the run's (same mesh, count and
seed), so outputs and errors are those of a run without it
(tests/test_launch.py).
"""

from __future__ import annotations

import sys
import time

#: When the process reached gamma (the start-up time summary.json reports runs from here).
STARTED = time.perf_counter()

from .options import EARLY  # noqa: E402 - after STARTED, which times gamma's own imports too


def read_options(argv: list[str]) -> tuple[str, int, int, int] | None:
    """(scene, surfels, seed, threads) of a ``gammac run`` command line, or
    None when they cannot be told for certain without argparse."""
    if not argv or argv[0] != "run":
        return None
    found: dict[str, str] = {}
    k = 1
    while k < len(argv):
        token = argv[k]
        k += 1
        if token == "--":
            break                        # everything after it is positional
        if not token.startswith("--"):
            continue
        name, eq, value = token.partition("=")
        if name in EARLY:
            if not eq:
                if k >= len(argv):
                    return None
                value = argv[k]
                k += 1
            found[name] = value          # argparse keeps the last one too
        elif any(full.startswith(name) for full in EARLY):
            return None                  # an abbreviation argparse may expand to one of them
    if "--scene" not in found:
        return None
    numbers = []
    for name in ("--surfels", "--seed", "--threads"):
        text = found.get(name)
        if text is None:
            numbers.append(EARLY[name])
        elif text.isascii() and text.isdigit():
            numbers.append(int(text))
        else:
            return None                  # argparse reports it
    return (found["--scene"], *numbers)


def main() -> None:
    """The ``gammac`` command."""
    import os

    # before numpy's import (cli.entry says why)
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    try:
        options = read_options(sys.argv[1:])
        if options is not None:
            try:
                from .driver.running import prefetch

                prefetch.start(*options)
            except Exception:  # noqa: BLE001 - only a head start: cli.main starts (or reports) it again
                pass
        from .cli import entry
    except KeyboardInterrupt:
        # ^C before cli.entry's handler: reported as it would (the exit stops the
        # sampling started here, prefetch._forget)
        sys.stderr.write("gammac: interrupted\n")
        sys.exit(130)
    entry()
