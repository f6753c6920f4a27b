"""What the check learns from the file system, learnt through here so that
it can be recorded and asked again.

The checker finds imports (next to the file, then in the standard library)
and textures by testing and resolving paths, and reads the imported files.
Inside ``with observing() as facts:`` every answer is appended to ``facts``;
the compiled-effect cache (backends/effect_cache.py) keeps them beside the
checked effect and trusts it only while ``fact_holds`` for every one.  This
module imports nothing heavy: a cached run asks its facts before it imports
the checker.
"""

from __future__ import annotations

from pathlib import Path

#: While ``observing``: what the check learnt from the file system, in order
#: (``("is_file", path, answer)``, ``("resolve", path, answer)``,
#: ``("read", path, sha256 of the text)``).  The compiled-effect cache
#: (backends/effect_cache.py) keeps them beside the checked effect and asks
#: them again before it trusts it.
_observed: list | None = None


class observing:
    """``with observing() as facts:`` records, into the list ``facts``, every
    file-system answer the check inside depends on (main thread only)."""

    def __enter__(self) -> list:
        global _observed
        self.outer, _observed = _observed, []
        return _observed

    def __exit__(self, *exc) -> None:
        global _observed
        _observed = self.outer


def _note(kind: str, path: Path, answer) -> None:
    if _observed is not None:
        _observed.append((kind, str(path), answer))


def is_file(path: Path) -> bool:
    try:
        answer = path.is_file()
    except (OSError, ValueError):
        answer = False
    _note("is_file", path, answer)
    return answer


def resolved(path: Path) -> Path:
    """``path.resolve()`` (absolute, symbolic links followed)."""
    answer = path.resolve()
    _note("resolve", path, str(answer))
    return answer


def read_text(path: Path) -> str:
    """The UTF-8 text of ``path`` (OSError, UnicodeDecodeError)."""
    text = path.read_text(encoding="utf-8")
    if _observed is not None:
        import hashlib

        _note("read", path, hashlib.sha256(text.encode("utf-8")).hexdigest())
    return text


def fact_holds(kind: str, path: str, answer) -> bool:
    """Whether the file system still answers ``answer`` (a fact ``observing``
    recorded); never raises."""
    try:
        if kind == "is_file":
            return is_file(Path(path)) == answer
        if kind == "resolve":
            return str(Path(path).resolve()) == answer
        if kind == "read":
            import hashlib

            text = Path(path).read_text(encoding="utf-8")
            return hashlib.sha256(text.encode("utf-8")).hexdigest() == answer
    except (OSError, ValueError, RuntimeError):   # RuntimeError: a symbolic-link loop
        return False
    return False
