"""gamma: weathering effects by gamma-ton tracing (Chen et al., SIGGRAPH 2005).

    frontend/   source text -> AST -> names bound -> typed IR; diagnostics; formatter
    ir/         the IR of an effect, and the built-ins declared once
    backends/   LLVM code generation + verify/optimise/JIT; reference interpreter
    driver/     the run loop over the C++ runtime (``gamma._runtime``), its
                writers (maps, renders, summary, export), scene loading
    abi.py      the compiler <-> runtime interface, declared once
    files.py    atomic file writes
    cli.py      the ``gammac`` command

Dependencies point one way: cli -> driver -> backends -> ir <- frontend; all -> abi.
"""


def _installed_version() -> str:
    # One version: CMakeLists.txt's project(VERSION), which pyproject.toml reads
    # (scikit-build-core regex provider) into the package metadata and CMake
    # compiles into the runtime.  The runtime's copy costs nothing to read (a
    # run loads it anyway); importlib.metadata costs ~40 ms of start-up.
    try:
        from ._runtime import RUNTIME_VERSION

        return RUNTIME_VERSION
    except ImportError:
        pass
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("gamma-weathering")
    except PackageNotFoundError:   # running from a source tree that was never installed
        return "0+unknown"


def __getattr__(name: str):
    # Everything is imported on first use, so that `gammac check` starts fast:
    # the Python API pulls in numpy, the driver and LLVM, the version the
    # package metadata.
    if name == "__version__":
        globals()["__version__"] = value = _installed_version()
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
        from .driver import runner
        return getattr(runner, name)
    raise AttributeError(f"module 'gamma' has no attribute '{name}'")


__all__ = ["compile", "run", "Result", "GammaError", "UsageError", "RunError", "RunInterrupted", "__version__"]
