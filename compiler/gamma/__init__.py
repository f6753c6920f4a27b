"""gamma: weathering effects by gamma-ton tracing (Chen et al., SIGGRAPH 2005).

Compiler pipeline: ``parser`` (lark) -> ``ast`` -> ``checker`` -> ``codegen``
(llvmlite IR) -> ``backend`` (verify, optimise, JIT).  ``interp`` is the
reference interpreter over the same AST.  ``runner`` drives the C++ runtime
(``gamma._runtime``); ``cli`` is the ``gammac`` command.
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
