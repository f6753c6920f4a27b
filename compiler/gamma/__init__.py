"""gamma: weathering effects by gamma-ton tracing (Chen et al., SIGGRAPH 2005).

    frontend/   source text -> AST -> names bound -> typed IR; diagnostics; formatter
    ir/         the IR of an effect, and the built-ins declared once
    backends/   LLVM code generation + verify/optimise/JIT; reference interpreter
    driver/     the run loop over the C++ runtime (``gamma._runtime``), its
                writers (maps, renders, summary, export), scene loading
    abi.py      the compiler <-> runtime interface, declared once
    options.py  the options of a run, declared once (flags, defaults, limits)
    files.py    atomic file writes
    background.py  one call on a daemon thread (caches, read-ahead)
    version.py  the version, looked up on first use
    api.py      the Python API (``gamma.compile``, ``gamma.run``)
    cli.py      the ``gammac`` command (``launch.py``: its entry point)

Dependencies point one way: cli, api -> driver -> backends -> ir <- frontend;
all -> abi, options; no cycles, counting imports inside functions
(tests/test_architecture.py).  Importing ``gamma`` imports none of them: the
names below are looked up on first use.
"""


def __getattr__(name: str):
    # Everything is imported on first use, so that `gammac check` starts fast:
    # the Python API pulls in numpy, the driver and LLVM, the version the
    # package metadata.
    if name == "__version__":
        from .version import version

        globals()["__version__"] = value = version()
        return value
    if name in ("compile", "run", "Result"):
        from . import api
        return getattr(api, name)
    if name == "GammaError":
        from .frontend.diagnostics import GammaError
        return GammaError
    if name == "UsageError":
        from .frontend.checker import UsageError
        return UsageError
    if name in ("RunError", "RunInterrupted"):
        from .driver.running import runner
        return getattr(runner, name)
    raise AttributeError(f"module 'gamma' has no attribute '{name}'")


__all__ = ["compile", "run", "Result", "GammaError", "UsageError", "RunError", "RunInterrupted", "__version__"]
