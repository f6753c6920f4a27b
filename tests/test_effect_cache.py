"""gammac run keeps the checked effect and its kernels as a shared object
(gamma/backends/effect_cache.py): a rerun imports neither the parser (lark)
nor LLVM (llvmlite) and writes the same files; the shared object computes
what the JIT's code computes, bit for bit; whatever the check learnt from
the file system (imports found, shadowed, changed; textures) is asked again;
a damaged entry or shared object is never used; without a C compiler
nothing is kept and nothing breaks."""

import ctypes
import json
import os
import subprocess
import sys

import numpy as np
import pytest

from conftest import ROOT
from test_kernels import HEADER, TRANSPORT, UPDATE, GammaContext, ptr, same, set_key
from test_prefetch import folder_hash

from gamma.backends import effect_cache
from gamma.backends.jit import JitKernels
from gamma.frontend.diagnostics import GammaError
from gamma.ir.builtins import FUNCTIONS

BUNNY = ROOT / "examples" / "scenes" / "stanford-bunny.obj"

#: gammac run in this interpreter, then the names of the modules it imported
#: that a rerun should not need, written to the file $IMPORTED.
SCRIPT = """
import os, sys
from gamma import cli
status = cli.main(sys.argv[1:])
with open(os.environ["IMPORTED"], "w") as f:
    f.write(",".join(sorted({m.split(".")[0] for m in sys.modules} & {"lark", "llvmlite"})))
sys.exit(status)
"""


def run(tmp_path, cache, name, effect=ROOT / "examples" / "patina.gamma", *extra, env=None):
    """gammac run (bunny, 3000 surfels) with the cache folder ``cache``: its
    output folder, summary, stderr and the parser/LLVM modules it imported."""
    out = tmp_path / name
    imported = tmp_path / f"{name}.imported"
    args = ["run", effect, "--scene", BUNNY, "--surfels", "3000", "--tons", "20000",
            "--iterations", "2", "--threads", "2", "--quiet", "--out", out, *extra]
    r = subprocess.run([sys.executable, "-c", SCRIPT, *map(str, args)], capture_output=True, text=True,
                       timeout=600, env=dict(env or os.environ, GAMMA_CACHE_DIR=str(cache),
                                             IMPORTED=str(imported)))
    assert r.returncode == 0, r.stderr
    summary = json.loads((out / "summary.json").read_text())
    return out, summary, r.stderr, imported.read_text().split(",") if imported.read_text() else []


def entries(cache):
    return sorted(p.name for p in cache.glob("effect-*"))


def test_a_rerun_takes_the_effect_and_its_shared_object_and_writes_the_same_files(tmp_path):
    cache = tmp_path / "cache"
    first, summary, _, imported = run(tmp_path, cache, "first")
    assert summary["kernels_from"] == "compiled" and imported == ["lark", "llvmlite"]
    assert sorted(n.rsplit(".", 1)[1] for n in entries(cache)) == ["bin", "so"]
    second, summary, _, imported = run(tmp_path, cache, "second")
    assert summary["kernels_from"] == "effect cache"
    assert imported == []                               # neither the parser nor LLVM
    assert summary["versions"]["llvm"] == json.loads((first / "summary.json").read_text())["versions"]["llvm"]
    off, summary, _, _ = run(tmp_path, "off", "off")
    assert summary["kernels_from"] == "compiled"
    assert folder_hash(first) == folder_hash(second) == folder_hash(off)


def test_warnings_are_printed_again_and_another_param_is_compiled_again(tmp_path):
    effect = tmp_path / "warned.gamma"
    effect.write_text("param unused = 1\n"
                      "ton T { motion straight = 1 carry a = 1 }\n"
                      "surface S { property p = 0 }\n"
                      "source s = environment(sphere) emits T count 10\n"
                      "on settle(t: T, s: S) { s.p += 0.5 * t.a }\n")
    cache = tmp_path / "cache"
    _, summary, first_err, _ = run(tmp_path, cache, "a", effect)
    assert "unused" in first_err and summary["kernels_from"] == "compiled"
    _, summary, second_err, _ = run(tmp_path, cache, "b", effect)
    assert summary["kernels_from"] == "effect cache"
    assert second_err.replace(f"{tmp_path}/b/", f"{tmp_path}/a/") == first_err
    _, summary, _, _ = run(tmp_path, cache, "c", effect, "--param", "unused=2")
    assert summary["kernels_from"] != "effect cache"


def every_builtin_body() -> str:
    """An update body that calls every scalar built-in on the row's values."""
    args = ["s.p", "s.q", "(s.p * 0.5 + 0.25)"]
    lines = []
    for name, fn in sorted(FUNCTIONS.items()):
        if fn.appearance_only or fn.args is not None or name == "random":
            continue
        if fn.string_arg:           # a name, not a value: a vertex attribute's column of the row
            if name == "attribute":  # (mask() needs an image on disk: test_scene_inputs reads them)
                lines.append('s.q += attribute("wetness")')
            continue
        count = fn.min_args if fn.max_args is None else fn.max_args
        lines.append(f"s.q += {name}({', '.join(args[i % 3] for i in range(count))})" if count else
                     f"s.q += {name}()")
    return "\n".join(lines + ["s.p = s.p * random() + s.q"])


# A run that ends (through the interpreter's exit) while its entry is still
# being kept: the C compiler is held until the main thread has left, so the
# exit begins with the compile's working folder in use.  A TemporaryDirectory's
# finalizer, run at exit before background's handler joins the thread, took
# that folder away, and no entry was kept (a rerun compiled again: seen in CI).
EXIT_WHILE_KEEPING = """
import os, subprocess, sys, threading, time
from pathlib import Path
from gamma.backends import effect_cache
compiling = threading.Event()
compile_library = subprocess.run
def held_compile(*args, **kwargs):
    compiling.set()
    time.sleep(0.5)
    return compile_library(*args, **kwargs)
subprocess.run = held_compile
effect = effect_cache.check(sys.argv[1], Path(sys.argv[1]).read_text(), {})
effect_cache.kernels_for(effect)
assert compiling.wait(120)
"""


def test_an_entry_being_kept_when_the_interpreter_exits_is_kept_whole(tmp_path):
    effect = tmp_path / "e.gamma"
    effect.write_text("ton T { motion straight = 1 carry a = 1 }\n"
                      "surface S { property p = 0 }\n"
                      "source s = environment(sphere) emits T count 10\n"
                      "on settle(t: T, s: S) { s.p += 0.5 * t.a }\n")
    cache = tmp_path / "cache"
    r = subprocess.run([sys.executable, "-c", EXIT_WHILE_KEEPING, str(effect)], capture_output=True, text=True,
                       timeout=300, env=dict(os.environ, GAMMA_CACHE_DIR=str(cache)), cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    kept = entries(cache)                             # the entry and its shared object
    assert len(kept) == 2 and kept[0].endswith(".so") and kept[1].endswith(".bin"), kept
    assert not list(cache.glob(".effect-*"))         # and no working folder left


def test_the_shared_object_computes_what_the_jit_computes(tmp_path, monkeypatch):
    monkeypatch.setenv("GAMMA_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.chdir(tmp_path)
    source = HEADER + ("on hit(t: T, s: S) {\n t.a = pow(abs(t.a), t.b) + noise(position) + fbm(position, 4)\n"
                       " s.q += exp(t.b) * random() + length(cross(normal, direction)) + dot(normal, direction)\n"
                       " s.p += length(normalize(direction)) * log(abs(t.a))\n}\n"
                       f"update(s: S) {{\n{every_builtin_body()}\n}}\n")
    jit_effect = effect_cache.check("every.gamma", source, {})
    jit = effect_cache.kernels_for(jit_effect)
    assert isinstance(jit, JitKernels)
    effect_cache.wait()
    effect = effect_cache.check("every.gamma", source, {})
    shared = effect_cache.kernels_for(effect)
    assert isinstance(shared, effect_cache.SharedKernels) and effect == jit_effect
    hit_k = next(k for k in effect.kernels if k.event == "hit")
    upd_k = next(k for k in effect.kernels if k.event == "update")
    rng = np.random.default_rng(7)
    special = np.array([0.0, -0.0, 1.0, -1.0, 0.5, 1e-42, 3.4e38, np.inf, -np.inf, np.nan, 123.25], np.float32)
    for _ in range(300):
        pick = lambda n: np.where(rng.random(n) < 0.3, rng.choice(special, n),
                                  rng.standard_normal(n) * 10.0 ** rng.integers(-3, 4, n)).astype(np.float32)
        ton, surf = pick(2), pick(effect.row_width)
        vec = pick(9)
        ctx = GammaContext(iteration=int(rng.integers(1, 50)), interactions=int(rng.integers(1, 10)),
                           position=(ctypes.c_float * 3)(*vec[0:3]), normal=(ctypes.c_float * 3)(*vec[3:6]),
                           direction=(ctypes.c_float * 3)(*vec[6:9]))
        set_key(ctx, int(rng.integers(0, 2**63)))
        results = []
        for kernels in (jit, shared):
            ton_c, delta, row = ton.copy(), np.zeros_like(surf), surf.copy()
            bad_hit = TRANSPORT(kernels.address[hit_k.symbol])(ptr(ton_c), ptr(surf), ptr(delta), ctypes.byref(ctx))
            bad_update = UPDATE(kernels.address[upd_k.symbol])(ptr(row), ctypes.byref(ctx))
            results.append((ton_c, delta, row, bad_hit, bad_update))
        (a_ton, a_delta, a_row, a_bh, a_bu), (b_ton, b_delta, b_row, b_bh, b_bu) = results
        assert same(a_ton, b_ton) and same(a_delta, b_delta) and same(a_row, b_row)
        assert (a_bh, a_bu) == (b_bh, b_bu)


def checked_from_cache(path, source="", overrides=None, given=None):
    """effect_cache.check of the file ``path`` (its text read now), named on
    the command line as ``given`` (default: its name), and whether the
    effect came from the cache."""
    text = source or path.read_text()
    effect = effect_cache.check(given or path.name, text, overrides or {})
    came = isinstance(effect_cache.kernels_for(effect), effect_cache.SharedKernels)
    effect_cache.wait()
    return effect, came


def test_what_the_check_saw_on_disk_is_asked_again(tmp_path, monkeypatch):
    monkeypatch.setenv("GAMMA_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.chdir(tmp_path)
    main = tmp_path / "main.gamma"
    main.write_text('import "patina.gamma"\n')
    effect, came = checked_from_cache(main)
    assert set(effect.tons) == {"Weather"} and not came     # the standard library's recipe
    effect, came = checked_from_cache(main)
    assert set(effect.tons) == {"Weather"} and came
    # a file next to the effect now shadows the standard library's
    (tmp_path / "patina.gamma").write_text(
        "ton Local { motion straight = 1 carry x = 1 }\nsurface S { property p = 0 }\n"
        "source s = environment(sphere) emits Local count 10\non settle(t: Local, s: S) { s.p += t.x }\n")
    effect, came = checked_from_cache(main)
    assert set(effect.tons) == {"Local"} and not came
    assert checked_from_cache(main)[1]
    # ... and is changed
    (tmp_path / "patina.gamma").write_text((tmp_path / "patina.gamma").read_text().replace("Local", "Other"))
    effect, came = checked_from_cache(main)
    assert set(effect.tons) == {"Other"} and not came
    # a texture that is gone is an error again, not a cached effect
    (tmp_path / "red.png").write_bytes(b"not read by the check")
    textured = tmp_path / "textured.gamma"
    textured.write_text(HEADER + 'appearance(s: S) { color = texture("red.png") }\n')
    assert not checked_from_cache(textured)[1] and checked_from_cache(textured)[1]
    (tmp_path / "red.png").unlink()
    with pytest.raises(GammaError, match="cannot find texture 'red.png'"):
        checked_from_cache(textured)
    # another working folder is another key (messages show paths relative to it)
    (tmp_path / "elsewhere").mkdir()
    monkeypatch.chdir(tmp_path / "elsewhere")
    assert not checked_from_cache(main, given=str(main))[1]


def test_a_damaged_entry_or_shared_object_is_not_used_and_is_replaced(tmp_path, monkeypatch):
    cache = tmp_path / "cache"
    monkeypatch.setenv("GAMMA_CACHE_DIR", str(cache))
    monkeypatch.chdir(tmp_path)
    main = tmp_path / "m.gamma"
    main.write_text(HEADER + "on settle(t: T, s: S) { s.p += t.a }\n")
    assert not checked_from_cache(main)[1] and checked_from_cache(main)[1]
    (entry,) = cache.glob("effect-*.bin")
    for name, cut in (("bin", False), ("so", False), ("bin", True)):
        (path,) = cache.glob(f"effect-*.{name}")
        data = bytearray(path.read_bytes())
        if cut:
            del data[len(data) // 2:]
        else:
            data[len(data) // 2] ^= 0x40
        path.write_bytes(bytes(data))
        effect, came = checked_from_cache(main)
        assert not came and set(effect.tons) == {"T"}
        assert checked_from_cache(main)[1]                  # written again, whole
    entry.write_bytes(b"garbage")
    assert effect_cache.load(entry.name[len("effect-"):-len(".bin")]) is None   # never raises


def test_without_a_c_compiler_nothing_is_kept_and_the_run_is_the_same(tmp_path):
    cache = tmp_path / "cache"
    bare = tmp_path / "bin"
    bare.mkdir()
    env = dict(os.environ, PATH=str(bare))
    first, summary, _, _ = run(tmp_path, cache, "first", env=env)
    assert summary["kernels_from"] == "compiled" and entries(cache) == []
    second, summary, _, _ = run(tmp_path, cache, "second", env=env)
    assert summary["kernels_from"] == "kernel cache"     # the JIT's machine code, as before
    assert folder_hash(first) == folder_hash(second)


def test_the_least_recently_used_entries_go_first(tmp_path, monkeypatch):
    cache = tmp_path / "cache"
    monkeypatch.setenv("GAMMA_CACHE_DIR", str(cache))
    monkeypatch.setattr(effect_cache, "MAX_ENTRIES", 2)
    monkeypatch.chdir(tmp_path)
    main = tmp_path / "m.gamma"
    for k in ("1", "2", "3"):
        main.write_text(HEADER + f"on settle(t: T, s: S) {{ s.p += t.a * {k} }}\n")
        checked_from_cache(main)
    assert len(list(cache.glob("effect-*.bin"))) == 2 and len(list(cache.glob("effect-*.so"))) == 2
    assert checked_from_cache(main)[1]                     # the newest is kept
    main.write_text(HEADER + "on settle(t: T, s: S) { s.p += t.a * 1 }\n")
    assert not checked_from_cache(main)[1]                 # the oldest is not


def test_the_working_folder_the_param_order_and_a_relative_cache_folder(tmp_path, monkeypatch):
    monkeypatch.setenv("GAMMA_CACHE_DIR", "cache")           # relative: in the working folder
    monkeypatch.chdir(tmp_path)
    (tmp_path / "lib.gamma").write_text("param unused = 1\n")
    main = tmp_path / "main.gamma"
    main.write_text('param a = 1\nparam b = 2\nimport "lib.gamma"\n' + HEADER
                    + "on settle(t: T, s: S) { s.p += t.a * a * b }\n")
    absolute = str(main.resolve())
    here, came = checked_from_cache(main, given=absolute)
    assert not came and checked_from_cache(main, given=absolute)[1]
    # the same absolute path from another folder: its messages name the import otherwise
    (tmp_path / "elsewhere").mkdir()
    monkeypatch.chdir(tmp_path / "elsewhere")
    monkeypatch.setenv("GAMMA_CACHE_DIR", str(tmp_path / "cache"))
    there, came = checked_from_cache(main, given=absolute)
    shown = lambda effect: next(w.file.path for w in effect.warnings if "'unused'" in w.message)
    assert not came and shown(here) == "lib.gamma" and shown(there) == str((tmp_path / "lib.gamma").resolve())
    # --param in another order is another check (the effect keeps the order given)
    monkeypatch.chdir(tmp_path)
    for overrides in ({"a": 3.0, "b": 4.0}, {"b": 4.0, "a": 3.0}):
        effect, came = checked_from_cache(main, main.read_text(), overrides)
        assert not came and list(effect.overrides) == list(overrides)
    assert checked_from_cache(main, main.read_text(), {"b": 4.0, "a": 3.0})[1]


def test_a_missing_library_or_a_failing_compiler_costs_only_time(tmp_path, monkeypatch):
    cache = tmp_path / "cache"
    monkeypatch.setenv("GAMMA_CACHE_DIR", str(cache))
    monkeypatch.chdir(tmp_path)
    main = tmp_path / "m.gamma"
    main.write_text(HEADER + "on settle(t: T, s: S) { s.p += t.a * 5 }\n")
    assert not checked_from_cache(main)[1]
    (library,) = cache.glob("effect-*.so")
    library.unlink()
    assert not checked_from_cache(main)[1] and checked_from_cache(main)[1]
    # a C compiler that fails: nothing kept, the kernels from the JIT
    main.write_text(HEADER + "on settle(t: T, s: S) { s.p += t.a * 6 }\n")
    failing = tmp_path / "bin"
    failing.mkdir()
    (failing / "cc").write_text("#!/bin/sh\nexit 1\n")
    (failing / "cc").chmod(0o755)
    monkeypatch.setenv("PATH", str(failing))
    before = entries(cache)
    effect, came = checked_from_cache(main)
    assert not came and entries(cache) == before and not checked_from_cache(main)[1]


def test_orphaned_libraries_and_stale_temporaries_are_removed(tmp_path, monkeypatch):
    cache = tmp_path / "cache"
    monkeypatch.setenv("GAMMA_CACHE_DIR", str(cache))
    monkeypatch.chdir(tmp_path)
    cache.mkdir()
    old = 1_000_000_000
    orphan = cache / "effect-0123-4567.so"
    young_orphan = cache / "effect-89ab-cdef.so"
    stale_file, stale_folder = cache / ".effect-dead.bin.x1", cache / ".effect-dead"
    fresh_file = cache / ".effect-live.bin.x2"
    for path in (orphan, young_orphan, stale_file, fresh_file):
        path.write_bytes(b"x")
    stale_folder.mkdir()
    (stale_folder / "kernels.o").write_bytes(b"x")
    for path in (orphan, stale_file, stale_folder):
        os.utime(path, (old, old))
    main = tmp_path / "m.gamma"
    main.write_text(HEADER + "on settle(t: T, s: S) { s.p += t.a * 7 }\n")
    checked_from_cache(main)
    assert not orphan.exists() and not stale_file.exists() and not stale_folder.exists()
    assert young_orphan.exists() and fresh_file.exists()      # perhaps another process's, being written
    assert checked_from_cache(main)[1]


def test_a_cache_folder_others_can_write_to_is_not_used(tmp_path):
    """Issue 33, item 8: the caches load machine code, so a folder other
    users may write to is passed over; the run works and says so once."""
    cache = tmp_path / "shared"
    cache.mkdir()
    cache.chmod(0o777)
    effect = tmp_path / "e.gamma"
    effect.write_text((ROOT / "examples" / "patina.gamma").read_text())
    r = subprocess.run([sys.executable, "-m", "gamma.cli", "run", str(effect), "--scene",
                        str(ROOT / "examples" / "scenes" / "teapot.obj"), "--surfels", "2000", "--tons", "2000",
                        "--iterations", "1", "--size", "16", "--quiet", "--out", str(tmp_path / "out")],
                       capture_output=True, text=True, timeout=300, env=dict(os.environ, GAMMA_CACHE_DIR=str(cache)))
    assert r.returncode == 0, r.stderr
    note = f"gammac: note: not using the cache folder '{cache}': other users can write to it"
    assert r.stderr.count(note) == 1, r.stderr
    assert not any(cache.iterdir()), "nothing was kept there"


def test_cache_entries_are_0600_in_0700_folders(tmp_path):
    """Issue 33, item 8: what the caches keep (kernels, libraries, set-ups,
    views) only their owner can read or replace, whatever the umask."""
    cache = tmp_path / "made" / "cache"
    effect = tmp_path / "e.gamma"
    effect.write_text((ROOT / "examples" / "patina.gamma").read_text())
    command = [sys.executable, "-c", "import os, sys; os.umask(0o002); from gamma.cli import main; "
               "sys.exit(main(sys.argv[1:]))", "run", str(effect), "--scene",
               str(ROOT / "examples" / "scenes" / "teapot.obj"), "--surfels", "2000", "--tons", "2000",
               "--iterations", "1", "--size", "16", "--quiet"]
    env = dict(os.environ, GAMMA_CACHE_DIR=str(cache))
    for k in range(2):      # the second run keeps what the first one's background work had not
        r = subprocess.run(command + ["--out", str(tmp_path / f"out{k}")], capture_output=True, text=True,
                           timeout=300, env=env)
        assert r.returncode == 0, r.stderr
    entries = [p for p in cache.rglob("*")]
    files = [p for p in entries if p.is_file()]
    assert any(p.suffix == ".so" for p in files) and any(p.name.startswith("setup-") for p in files), entries
    assert (cache.stat().st_mode & 0o777) == 0o700
    for p in entries:
        assert (p.stat().st_mode & 0o777) == (0o600 if p.is_file() else 0o700), (p, oct(p.stat().st_mode))
