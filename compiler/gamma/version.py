"""gamma's version: CMakeLists.txt's project(VERSION), which pyproject.toml
reads (scikit-build-core regex provider) into the package metadata and CMake
compiles into the runtime.  Looked up on first use (``gamma.__version__``,
the summary, the caches' keys)."""

_version: str | None = None


def version() -> str:
    global _version
    if _version is None:
        _version = _installed_version()
    return _version


def _installed_version() -> str:
    # The runtime's copy costs nothing to read (a run loads it anyway);
    # importlib.metadata costs start-up time (bench/RESULTS.md).
    try:
        from ._runtime import RUNTIME_VERSION

        return RUNTIME_VERSION
    except ImportError:
        pass
    from importlib.metadata import PackageNotFoundError, version as metadata_version

    try:
        return metadata_version("gamma-weathering")
    except PackageNotFoundError:   # running from a source tree that was never installed
        return "0+unknown"
