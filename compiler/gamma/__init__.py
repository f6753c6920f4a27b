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
    # (scikit-build-core regex provider) into the package metadata.
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("gamma-weathering")
    except PackageNotFoundError:   # running from a source tree that was never installed
        return "0+unknown"


__version__ = _installed_version()

from .api import Result, compile, run  # noqa: E402  (the Python API; see api.py)


def __getattr__(name: str):
    # the error types, imported on first use (they pull in the compiler and driver)
    if name == "GammaError":
        from .frontend.diagnostics import GammaError
        return GammaError
    if name == "UsageError":
        from .frontend.checker import UsageError
        return UsageError
    if name == "RunError":
        from .driver.runner import RunError
        return RunError
    raise AttributeError(f"module 'gamma' has no attribute '{name}'")
