"""The compiled-effect cache: ``gammac run`` of an effect it ran before
imports neither the parser (lark) nor LLVM (llvmlite).

Most of a rerun's start-up (all of it imports on one core) was lark, the
checker and llvmlite: the kernel cache (jit.py) kept the
machine code, but MCJIT, and so LLVM's 100 MB library, was still needed to
link it, and the effect was parsed and checked again.  After a run has
compiled an effect, this module keeps in ``cache_dir()``:

- ``effect-KEY-HASH.so``: the kernels as a shared object (HASH: of its
  bytes; a process never loads two libraries of one name, so a newer one
  of the same KEY gets a name of its own): the same IR, optimised
  by the same pipeline for the same CPU as the JIT's, emitted
  position-independent (``jit.position_independent_object``) and linked by
  the system's C compiler (``cc -shared``);
- ``effect-KEY.bin``: the checked ``Effect`` (pickled), the file-system
  facts its check depended on (every file it read, with its SHA-256, and
  every path it tested or resolved, with the answer: ``filefacts.observing``),
  the kernels' IR text (a run's resume key hashes it), the LLVM version and
  the SHA-256 of the shared object; the whole behind its own SHA-256.

KEY hashes what the check and the code depend on besides those facts: the
compiler (every ``.py`` and ``.lark`` file of the package, and where it is;
the grammar), Python's version, lark and llvmlite's library as installed,
the CPU (``/proc/cpuinfo``'s model and flags: the JIT compiles for the host
CPU), the working folder (messages show paths relative to it), the effect
file's path as given and resolved, its text and the ``--param`` values in
their order.  A later run with the same
KEY asks the facts again (a few ``stat`` calls and reads); when every one
still holds it takes the ``Effect`` from the file and ``dlopen``s the
shared object (``kernels_for``) instead of parsing, checking and compiling.
Anything else (no C compiler, not Linux, a damaged, cut or foreign file, a
fact that changed, a symbol missing) falls back to the ordinary path, whose
run writes the entry again.  A run's outputs are the same, bit for bit,
either way (tests/test_effect_cache.py).  Like the kernel cache, the folder
holds machine code that gammac runs: it must be the user's own.
"""

from __future__ import annotations

import hashlib
import json
import os
import sys
import threading
from pathlib import Path

from .. import background
from ..files import CACHE_FOLDER_MODE, cache_dir, cache_write

#: ``effect-KEY.bin`` starts with this, then the SHA-256 of the pickle after it.
MAGIC = b"gamma-effect\x001\x00"

_lock = threading.Lock()
_writes = background.Pending()
#: id(effect) -> (effect, SharedKernels) for the effects ``load`` returned
_loaded: dict[int, tuple] = {}
#: id(effect) -> (effect, key, pickled effect, facts) for effects checked here, to keep
_unsaved: dict[int, tuple] = {}
_compiler: str | None = None


class SharedKernels:
    """The kernels of an effect in a shared object of the cache: what
    ``JitKernels`` offers the driver (``address``, ``ir_text``,
    ``llvm_version``, ``from_cache``).  The library stays loaded for the
    process's life (ctypes never unloads it)."""

    from_cache = True

    def __init__(self, path: Path, symbols: list[str], ir_text: str, llvm_version: tuple):
        import ctypes

        from .. import ownmath

        ownmath.make_global()  # the kernels' calls of gamma_expf, ... resolve to the loaded runtime
        # absolute: a name without a slash would be looked for in the system's folders
        self.library = ctypes.CDLL(os.path.abspath(path))
        self.address = {s: ctypes.cast(getattr(self.library, s), ctypes.c_void_p).value for s in symbols}
        self.ir_text = ir_text
        self.llvm_version = llvm_version


def _compiler_build() -> str:
    """A hash of the compiler itself: every source file of the package, and
    the grammar where the parser finds it (in a source checkout, outside)."""
    global _compiler
    if _compiler is None:
        package = Path(__file__).resolve().parent.parent
        h = hashlib.sha256(str(package).encode() + b"\0" + sys.version.encode() + b"\0")
        grammars = [package.parent.parent / "language" / "gamma.lark"]   # frontend/parser.grammar_path
        for path in sorted(p for p in package.rglob("*")
                           if p.suffix in (".py", ".lark") and "__pycache__" not in p.parts) + \
                [g for g in grammars if g.is_file()]:
            h.update(str(path).encode() + b"\0")
            h.update(path.read_bytes())
        _compiler = h.hexdigest()
    return _compiler


def _installed(package: str, *files: str) -> str:
    """Where ``package`` is installed and the size and time of the first of
    ``files`` it has (the package is not imported)."""
    import importlib.util

    spec = importlib.util.find_spec(package)
    for folder in (spec.submodule_search_locations or ()) if spec else ():
        for name in files:
            path = Path(folder) / name
            if path.is_file():
                st = path.stat()
                return f"{path}|{st.st_size}|{st.st_mtime_ns}"
    raise OSError(f"{package} not found")


def _cpu() -> str:
    """The CPU as the JIT sees it (its model and features), from /proc/cpuinfo."""
    wanted = ("vendor_id", "cpu family", "model", "model name", "stepping", "flags")
    found = {}
    with open("/proc/cpuinfo", encoding="utf-8", errors="replace") as f:
        for line in f:
            if not line.strip():
                break                       # the first processor is enough
            name, _, value = line.partition(":")
            if name.strip() in wanted:
                found[name.strip()] = value.strip()
    if "flags" not in found:
        raise OSError("no CPU flags in /proc/cpuinfo")
    return json.dumps(found, sort_keys=True)


def key_for(path: str, source: str, overrides: dict) -> str | None:
    """The cache key of checking ``source`` (the file ``path``) with
    ``overrides``, or None (the cache off, or not on this system)."""
    if cache_dir() is None or not sys.platform.startswith("linux"):
        return None
    try:
        from .. import abi

        # the parser (lark) and LLVM (llvmlite's library) as installed; --param in the order
        # given (the effect keeps it)
        parts = [_compiler_build(), str(abi.ABI_VERSION), _installed("lark", "__init__.py"),
                 _installed("llvmlite", "binding/libllvmlite.so", "binding/libllvmlite.dylib",
                            "binding/llvmlite.dll"), _cpu(), os.getcwd(), path, str(Path(path).resolve()),
                 json.dumps(list(overrides.items())), source]
    except (OSError, ValueError, RuntimeError, AttributeError):
        return None
    return hashlib.sha256("\0".join(parts).encode("utf-8", "surrogatepass")).hexdigest()[:40]


def load(key: str | None):
    """The checked Effect kept under ``key``, its kernels loaded
    (``kernels_for`` hands them out), or None.  Never raises."""
    folder = cache_dir()
    if key is None or folder is None:
        return None
    entry = folder / f"effect-{key}.bin"
    try:
        blob = entry.read_bytes()
    except OSError:
        return None
    try:
        import pickle

        from ..frontend.filefacts import fact_holds

        head = len(MAGIC) + 32
        if not blob.startswith(MAGIC) or hashlib.sha256(blob[head:]).digest() != blob[len(MAGIC):head]:
            raise ValueError("not an intact entry")
        kept = pickle.loads(blob[head:])
        if kept["key"] != key:
            raise ValueError("another key's entry")
        if not all(fact_holds(*fact) for fact in kept["facts"]):
            return None                      # an import or texture changed: checked again, kept again
        shared = folder / _library_name(key, kept["shared_sha256"])
        if hashlib.sha256(shared.read_bytes()).hexdigest() != kept["shared_sha256"]:
            raise ValueError("the shared object is not the one compiled")
        effect = pickle.loads(kept["effect"])
        kernels = SharedKernels(shared, kept["symbols"], kept["ir_text"], tuple(kept["llvm_version"]))
    except Exception:  # noqa: BLE001 - anything wrong with an entry: compiled again, and replaced
        return None
    try:
        os.utime(entry)
    except OSError:
        pass
    with _lock:
        _loaded[id(effect)] = (effect, kernels)
    return effect


def check(path: str, source: str, overrides: dict):
    """``source`` parsed and checked (GammaError, UsageError as always),
    from the cache when it keeps it; a new check is kept after the run
    compiles its kernels (``kernels_for``)."""
    key = key_for(path, source, overrides)
    effect = load(key)
    if effect is not None:
        return effect
    from ..frontend.checker import check as check_module
    from ..frontend.parser import parse
    from ..frontend.filefacts import observing

    with observing() as facts:
        effect = check_module(parse(source, path), overrides)
    if key is not None:
        try:
            import pickle

            pickled = pickle.dumps(effect, protocol=pickle.HIGHEST_PROTOCOL)   # before anyone changes it
        except Exception:  # noqa: BLE001 - an effect that cannot be kept is only not kept
            return effect
        with _lock:
            _unsaved[id(effect)] = (effect, key, pickled, list(facts))
    return effect


def kernels_for(effect):
    """The machine code of ``effect``'s kernels: the shared object ``load``
    opened with it, else compiled now (``JitKernels``), in which case a
    shared object of them is made and the entry kept, behind the run."""
    with _lock:
        loaded = _loaded.get(id(effect))
        unsaved = _unsaved.pop(id(effect), None)
    if loaded is not None and loaded[0] is effect:
        return loaded[1]
    from .jit import JitKernels

    kernels = JitKernels(effect)
    if unsaved is not None and unsaved[0] is effect:
        outcome = background.start(_keep, unsaved[1:], kernels.ir_text, sorted(kernels.address),
                                   kernels.llvm_version, name="gamma-effect-cache")
        _writes.add(outcome)
    return kernels


def _library_name(key: str, digest: str) -> str:
    return f"effect-{key}-{digest[:16]}.so"


def _keep(unsaved: tuple, ir_text: str, symbols: list[str], llvm_version: tuple) -> None:
    """Make the shared object and write the entry; never raises."""
    import pickle
    import shutil
    import subprocess
    import tempfile

    key, pickled, facts = unsaved
    folder = cache_dir()
    compiler = shutil.which("cc") or shutil.which("gcc") or shutil.which("clang")
    if folder is None or compiler is None:
        return
    try:
        from .jit import position_independent_object

        code = position_independent_object(ir_text)
        folder.mkdir(mode=CACHE_FOLDER_MODE, parents=True, exist_ok=True)
        # not a TemporaryDirectory: its finalizer runs at the interpreter's exit, before
        # background's handler joins this thread, and took the folder from under the
        # compiler (no entry kept when the run ended first: seen in CI)
        work = tempfile.mkdtemp(prefix=".effect-", dir=folder)
        try:
            objfile, library = Path(work) / "kernels.o", Path(work) / "kernels.so"
            objfile.write_bytes(code)
            subprocess.run([compiler, "-shared", "-o", str(library), str(objfile), "-lm"], check=True,
                           stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                           stderr=subprocess.DEVNULL, timeout=120)
            shared = library.read_bytes()
        finally:
            shutil.rmtree(work, ignore_errors=True)
        digest = hashlib.sha256(shared).hexdigest()
        # An older library of this key goes (its entry is replaced next).  Another process
        # keeping the same key at the same time may remove ours in turn: its entry then
        # names a library that is gone, and the next run compiles and keeps it again.
        for older in folder.glob(f"effect-{key}-*.so"):
            _unlink(str(older))
        cache_write(folder / _library_name(key, digest), shared)
        body = pickle.dumps({"key": key, "effect": pickled, "facts": facts,
                             "ir_text": ir_text, "symbols": symbols, "llvm_version": list(llvm_version),
                             "shared_sha256": digest},
                            protocol=pickle.HIGHEST_PROTOCOL)
        cache_write(folder / f"effect-{key}.bin", (MAGIC, hashlib.sha256(body).digest(), body))
        _trim(folder)
    except Exception:  # noqa: BLE001 - an entry not kept only costs the next run time
        return


#: Entries kept at most; the least recently used are removed first.
MAX_ENTRIES = 200
#: A temporary file or folder older than this was left by a process that
#: died while keeping an entry (that takes well under a minute).
STALE_TEMPORARY_SECONDS = 3600


def _trim(folder: Path) -> None:
    """Remove the least recently used entries beyond MAX_ENTRIES, shared
    objects no entry names, and the temporaries of writes that never ended.
    Other processes may be removing the same files: each is tried alone."""
    import shutil
    import time

    entries, libraries = [], []
    for e in os.scandir(folder):
        try:
            st = e.stat()
        except OSError:
            continue
        if e.name.startswith(".effect-") and time.time() - st.st_mtime > STALE_TEMPORARY_SECONDS:
            shutil.rmtree(e.path, ignore_errors=True) if e.is_dir() else _unlink(e.path)
        elif e.name.startswith("effect-") and e.name.endswith(".bin"):
            entries.append((st.st_mtime_ns, e.name[:-len(".bin")]))
        elif e.name.startswith("effect-") and e.name.endswith(".so") and time.time() - st.st_mtime > 60:
            libraries.append(e.name)        # (a young one may be an entry's, its .bin being written)
    entries.sort()
    removed = {stem for _, stem in entries[:max(0, len(entries) - MAX_ENTRIES)]}
    kept = {stem for _, stem in entries} - removed
    for stem in removed:
        for path in [os.path.join(folder, stem + ".bin"), *map(str, Path(folder).glob(f"{stem}-*.so"))]:
            _unlink(path)
    for name in libraries:
        if name.rsplit("-", 1)[0] not in kept:
            _unlink(os.path.join(folder, name))


def _unlink(path: str) -> None:
    try:
        os.unlink(path)
    except OSError:
        pass


def wait() -> None:
    """Wait for the entries being kept (before the process ends)."""
    _writes.wait()
