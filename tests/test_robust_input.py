"""Adversarial input (issue 13): malformed meshes and scenes, absurd numbers,
odd file kinds and odd text.  Each ends in one clear message, the documented
exit status (SPEC §16.2), no traceback, no hang and bounded memory."""

import json
import os
import re
import signal
import struct
import subprocess
import sys
import time
import zlib

import pytest

from conftest import ROOT, run_gammac
from test_bad_input import assert_one_line_error

PATINA = ROOT / "examples" / "patina.gamma"
BUNNY = ROOT / "examples" / "scenes" / "stanford-bunny.obj"
HEADER = ("ton T { motion straight = 1.0; carry a = 1.0 }\nsurface S { property p = 0 }\n"
          "source x = directional(down) emits T count 10\n")


def small_run(tmp_path, *args, effect=PATINA, scene=BUNNY, out="out"):
    return run_gammac("run", effect, "--scene", scene, "--surfels", 300, "--tons", 300,
                      "--iterations", 1, "--size", 16, "--quiet", "--out", tmp_path / out, *args)


# ---- meshes ------------------------------------------------------------------------

LOADER = """
import json, resource, sys
resource.setrlimit(resource.RLIMIT_AS, (3 << 30, 3 << 30))   # bounded memory, asserted
sys.path.insert(0, sys.argv[1])
from mesh_corpus import load
for path in sys.argv[2:]:
    print(json.dumps(load(path)), flush=True)
"""


def test_mesh_corpus(tmp_path):
    """Every file of the generated corpus (OBJ, PLY, glTF) loads or is refused
    with the expected message naming the file, within a memory limit and a
    time limit (no loop, no allocation of a declared 10^11 vertices, no
    decoding of a 12000x12000 texture)."""
    from fuzz_meshes import REGRESSIONS
    from mesh_corpus import write

    corpus = write(tmp_path / "corpus") + [(p, "any") for p in sorted(REGRESSIONS.glob("*"))]
    r = subprocess.run([sys.executable, "-c", LOADER, str(ROOT / "tests"), *[str(p) for p, _ in corpus]],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]
    assert r.stderr == ""                                  # no warnings either
    outcomes = [json.loads(line) for line in r.stdout.splitlines()]
    assert len(outcomes) == len(corpus)
    for (path, expected), outcome in zip(corpus, outcomes):
        assert "\n" not in str(outcome[1])                 # one line
        if expected == "any":
            continue
        if expected == "ok":
            assert outcome[0] == "ok", (path.name, outcome)
        else:
            assert outcome[0] == "error" and expected in outcome[1], (path.name, expected, outcome)
            assert str(path) in outcome[1], outcome      # the message names the file
    assert sum(o[0] == "error" for o in outcomes) > 90
    assert sum(p.suffix in (".gltf", ".glb") and o[0] == "error" for (p, _), o in zip(corpus, outcomes)) > 45


#: A few malformed glTF files of the corpus, run end to end: `gammac run`
#: exits with status 1 (SPEC §16.2) and one line naming the file.
GLTF_RUN_CASES = ["glb_cut_in_bin.glb", "bad_json.gltf", "view_too_long.gltf", "accessor_huge_count.gltf",
                  "data_uri_not_base64.gltf", "missing_bin.gltf", "nan_position.glb", "indices_out_of_range.glb",
                  "texture_bomb.glb"]


@pytest.mark.parametrize("name", GLTF_RUN_CASES)
def test_malformed_gltf_run_is_one_line_error(tmp_path, name):
    from mesh_corpus import GLTF_ERRORS, write

    write(tmp_path / "corpus")
    r = small_run(tmp_path, scene=tmp_path / "corpus" / name)
    assert_one_line_error(r, str(tmp_path / "corpus" / name), GLTF_ERRORS[name])
    assert not (tmp_path / "out").exists()


def test_degenerate_ply_face_is_dropped_with_a_warning(tmp_path):
    from mesh_corpus import TETRA_F, ply_ascii

    (tmp_path / "m.ply").write_bytes(ply_ascii(faces=TETRA_F + [(0, 0, 1)]))
    r = small_run(tmp_path, scene=tmp_path / "m.ply")
    assert r.returncode == 0, r.stderr
    assert "gammac: warning: 1 degenerate triangles of" in r.stderr


def test_latin1_group_name(tmp_path):
    from mesh_corpus import obj

    (tmp_path / "m.obj").write_bytes(obj(prefix=b"g Fa\xe7ade\n"))
    assert_one_line_error(small_run(tmp_path, scene=tmp_path / "m.obj"), "m.obj", "line 1",
                          "group name is not UTF-8")


def test_fifo_and_directory_as_files(tmp_path):
    os.mkfifo(tmp_path / "pipe.obj")
    os.mkfifo(tmp_path / "pipe.gamma")
    os.mkfifo(tmp_path / "pipe.json")
    (tmp_path / "dir.json").mkdir()
    assert_one_line_error(small_run(tmp_path, scene=tmp_path / "pipe.obj"), "pipe.obj", "not a regular file")
    assert_one_line_error(small_run(tmp_path, scene=tmp_path / "pipe.json"), "pipe.json", "not a regular file")
    assert_one_line_error(small_run(tmp_path, scene=tmp_path / "dir.json"), "dir.json", "is a directory")
    assert_one_line_error(run_gammac("check", tmp_path / "pipe.gamma", timeout=30), "not a regular file")
    assert_one_line_error(run_gammac("check", tmp_path, timeout=30), "is a directory")


def test_deeply_nested_scene_file(tmp_path):
    (tmp_path / "deep.json").write_text('{"meshes": ' + "[" * 100000 + "]" * 100000 + "}")
    assert_one_line_error(small_run(tmp_path, scene=tmp_path / "deep.json"), "deep.json", "nested too deeply")


@pytest.mark.parametrize("entry, down, where", [
    ({"scale": True}, None, "meshes[0].scale"),
    ({"translate": [0, True, 0]}, None, "meshes[0].translate"),
    ({"rotate": [False, 0, 0]}, None, "meshes[0].rotate"),
    ({}, [0, True, 0], "down"),
])
def test_scene_numbers_are_not_true_or_false(tmp_path, entry, down, where):
    """JSON's true and false are not numbers (Python's bool is an int, so they read as 1 and 0 before)."""
    spec = {"meshes": [{"file": str(BUNNY), **entry}]}
    if down is not None:
        spec["down"] = down
    (tmp_path / "s.json").write_text(json.dumps(spec))
    assert_one_line_error(small_run(tmp_path, scene=tmp_path / "s.json"), "s.json", where,
                          "must be a list of 3 finite numbers")


def test_a_ply_face_of_two_vertices_is_an_error_naming_it(tmp_path):
    from mesh_corpus import ply_ascii

    (tmp_path / "m.ply").write_bytes(ply_ascii(face_lines=["3 0 1 2", "3 0 2 3", "2 1 3"], face_count=3))
    assert_one_line_error(small_run(tmp_path, scene=tmp_path / "m.ply"), "m.ply",
                          "face 2 has fewer than 3 vertices (2)")


@pytest.mark.parametrize("scale", [1e-30, 1e30])
def test_scene_scaled_out_of_range_is_refused(tmp_path, scale):
    (tmp_path / "s.json").write_text(json.dumps({"meshes": [{"file": str(BUNNY), "scale": scale}]}))
    assert_one_line_error(small_run(tmp_path, scene=tmp_path / "s.json"), "s.json", "scene's size",
                          "1e-05 to 1e+10")


def test_scene_scale_does_not_change_the_counts(tmp_path):
    """Inside the stated range a scaled scene gives the same interactions."""
    counts = []
    for scale in (1e-3, 1.0, 1e3):
        (tmp_path / f"s{scale}.json").write_text(json.dumps({"meshes": [{"file": str(BUNNY), "scale": scale}]}))
        r = small_run(tmp_path, scene=tmp_path / f"s{scale}.json", out=f"o{scale}")
        assert r.returncode == 0, r.stderr
        it = json.loads((tmp_path / f"o{scale}" / "summary.json").read_text())["iterations"][0]
        counts.append((it["settled"], it["escaped"], it["interactions"]))
    assert counts[0] == counts[1] == counts[2]
    assert counts[1][0] > 0


# ---- absurd numbers --------------------------------------------------------------------


def test_far_point_source_is_refused(tmp_path):
    (tmp_path / "far.gamma").write_text(PATINA.read_text().replace(
        "environment(sphere)", "point(position = (1e20, 0, 0))"))
    assert_one_line_error(small_run(tmp_path, effect=tmp_path / "far.gamma"),
                          "source 'air' at (1e+20, 0, 0)", "within 1000 scene diagonals")


def test_far_camera_is_refused(tmp_path):
    assert_one_line_error(small_run(tmp_path, "--eye", "1e30,0,0"), "--eye at (1e+30, 0, 0)",
                          "within 1000 scene diagonals")
    assert not (tmp_path / "out").exists()


def test_run_that_cannot_fit_in_memory_is_refused_up_front(tmp_path):
    r = run_gammac("run", PATINA, "--scene", BUNNY, "--surfels", 20_000_000, "--iterations", 1_000_000,
                   "--quiet", "--out", tmp_path / "out", timeout=60)
    assert_one_line_error(r, "this run needs about", "GB of memory", "are available")
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("option,value", [("--seed", "٣"), ("--surfels", "１００"), ("--fov", "٣٠"),
                                          ("--eye", "١,0,0"), ("--param", "rate=٣")])
def test_non_ascii_digits_are_usage_errors(tmp_path, option, value):
    r = run_gammac("run", PATINA, "--scene", BUNNY, "--out", tmp_path / "o", option, value)
    assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr
    assert f"argument {option}" in r.stderr


def test_empty_out_is_refused(tmp_path):
    r = run_gammac("run", PATINA, "--scene", BUNNY, "--out", "", cwd=tmp_path)
    assert r.returncode == 2 and r.stderr.strip() == "gammac: error: --out must name a folder (it is empty)"
    assert list(tmp_path.iterdir()) == []


# ---- textures -------------------------------------------------------------------------------


def png_header_only(width: int, height: int) -> bytes:
    """A PNG that declares a huge image over a few bytes of data (a decompression bomb)."""
    def chunk(kind, data):
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    ihdr = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr)
            + chunk(b"IDAT", zlib.compress(b"\0" * 100000, 9)) + chunk(b"IEND", b""))


@pytest.mark.parametrize("size", [(9000, 10), (60000, 60000)])
def test_oversized_texture_is_refused_before_decoding(tmp_path, size):
    (tmp_path / "bomb.png").write_bytes(png_header_only(*size))
    (tmp_path / "e.gamma").write_text(PATINA.read_text() + (
        '\nappearance(s: Copper) {\n    color = texture("bomb.png")\n}\n'))
    r = small_run(tmp_path, effect=tmp_path / "e.gamma")
    assert_one_line_error(r, "bomb.png")
    assert f"{size[0]}x{size[1]} pixels" in r.stderr or "exceeds limit" in r.stderr


def test_texture_that_is_a_fifo(tmp_path):
    os.mkfifo(tmp_path / "t.png")
    (tmp_path / "e.gamma").write_text(PATINA.read_text() + (
        '\nappearance(s: Copper) {\n    color = texture("t.png")\n}\n'))
    r = check(tmp_path / "e.gamma")
    assert r.returncode in (0, 1) and "Traceback" not in r.stderr
    if r.returncode == 0:
        assert_one_line_error(small_run(tmp_path, effect=tmp_path / "e.gamma"), "t.png", "not a regular file")


# ---- effect files ------------------------------------------------------------------------------


def check(path):
    return run_gammac("check", path, timeout=60)


@pytest.mark.parametrize("path,message", [
    ('a\0b.gamma', "cannot import 'a\\x00b.gamma': a file name cannot contain a NUL character"),
    ("x" * 300 + ".gamma", "the file name is too long"),
    ("d/" * 3000 + "x.gamma", "the file name is too long"),
])
def test_bad_import_paths(tmp_path, path, message):
    (tmp_path / "e.gamma").write_text(f'import "{path}"\n' + HEADER)
    r = check(tmp_path / "e.gamma")
    assert r.returncode == 1 and "Traceback" not in r.stderr
    assert r.stderr.startswith("e.gamma:1:8: error: ") or ":1:8: error: " in r.stderr.splitlines()[0]
    assert message in r.stderr


@pytest.mark.parametrize("path,message", [
    ('a\0.png', "a file name cannot contain a NUL character"),
    ("x" * 300 + ".png", "the file name is too long"),
])
def test_bad_texture_paths(tmp_path, path, message):
    (tmp_path / "e.gamma").write_text(HEADER + f'appearance(s: S) {{\n    color = texture("{path}")\n}}\n')
    r = check(tmp_path / "e.gamma")
    assert r.returncode == 1 and "Traceback" not in r.stderr and ":5:21: error: cannot read texture" in r.stderr
    assert message in r.stderr


def test_byte_order_mark_is_accepted(tmp_path):
    (tmp_path / "e.gamma").write_bytes(b"\xef\xbb\xbf" + PATINA.read_bytes())
    r = check(tmp_path / "e.gamma")
    assert r.returncode == 0, r.stderr


@pytest.mark.parametrize("separator", ["\f", "\x85", "\u2028", "\u2029", "\x0b", "\x1c"])
def test_other_line_separators_do_not_shift_line_numbers(tmp_path, separator):
    text = f"// a comment{separator}with a separator\n" + HEADER + "on hit(t: T, s: S) {\n    s.q += 1\n}\n"
    (tmp_path / "e.gamma").write_text(text, encoding="utf-8")
    r = check(tmp_path / "e.gamma")
    assert r.returncode == 1
    head, source_line = r.stderr.splitlines()[:2]
    assert ":6:5: error: surface S has no property 'q'" in head, r.stderr
    assert source_line.strip() == "s.q += 1"


@pytest.mark.parametrize("separator, shown", [("\f", "\\f"), ("\x85", "\\x85"), ("\u2028", "\\u2028"),
                                              ("\x0b", "\\v")])
def test_an_echoed_line_with_a_separator_is_whole_and_escaped(tmp_path, separator, shown):
    """The echoed source line is the whole line (splitlines would cut it at the separator), escaped."""
    text = HEADER + f"on hit(t: T, s: S) {{\n    s.q += 1 // wet{separator}dry\n}}\n"
    (tmp_path / "e.gamma").write_text(text, encoding="utf-8")
    r = check(tmp_path / "e.gamma")
    assert r.returncode == 1
    head, source_line, caret = r.stderr.splitlines()[:3]
    assert ":5:5: error: surface S has no property 'q'" in head, r.stderr
    assert source_line == f"        s.q += 1 // wet{shown}dry", source_line
    assert caret == "        ^~~", caret


@pytest.mark.parametrize("text", [
    HEADER + "on hit(t: T, s: S) {\n    s.p += 1\n",
    HEADER + "surface Q { property p = \n",
    HEADER + "on hit(t: T, s: S) { s.p += 1 }\n}\n",
    HEADER + "on hit(t: T, s: S) { s.p += (1 }\n" + HEADER.replace("T", "U").replace("S", "R"),
])
def test_no_lark_internal_names_in_syntax_errors(tmp_path, text):
    (tmp_path / "e.gamma").write_text(text)
    r = check(tmp_path / "e.gamma")
    assert r.returncode == 1 and "Traceback" not in r.stderr
    for internal in ("$end", "$END", "__", "RBRACE", "LPAR"):
        assert internal not in r.stderr, r.stderr


def nested_ifs(n):
    return HEADER + "on hit(t: T, s: S) {\n" + "if t.a > 0 {\n" * n + "s.p += 1\n" + "}\n" * n + "}\n"


def test_deep_nesting_is_reported_at_its_position(tmp_path):
    (tmp_path / "deep.gamma").write_text(nested_ifs(300))
    r = check(tmp_path / "deep.gamma")
    assert r.returncode == 1 and "Traceback" not in r.stderr
    head = r.stderr.splitlines()[0]
    assert "nesting too deep" in head and "split it with 'let'" in head
    line = int(head.split(":")[1])
    assert 60 < line < 300                 # where the limit is crossed, not line 1


@pytest.mark.parametrize("text", [
    nested_ifs(70),
    HEADER + "on hit(t: T, s: S) { s.p += " + "(" * 500 + "t.a" + ")" * 500 + " }\n",
    HEADER + "on hit(t: T, s: S) { s.p += " + " + ".join(["t.a"] * 140) + " }\n",
    HEADER + "on hit(t: T, s: S) { if " + "not " * 140 + "t.a > 0 { s.p += 1 } }\n",
])
def test_nesting_below_the_limit_compiles(tmp_path, text):
    (tmp_path / "e.gamma").write_text(text)
    for command in (["check"], ["emit", "--ir"], ["fmt"]):
        r = run_gammac(*command, tmp_path / "e.gamma", timeout=120)
        assert r.returncode == 0, (command, r.stderr[-500:])


def test_fmt_write_on_a_read_only_file(tmp_path):
    path = tmp_path / "e.gamma"
    path.write_text(PATINA.read_text().replace("    s.patina", "s.patina"))
    before = path.read_bytes()
    path.chmod(0o444)
    r = run_gammac("fmt", "--write", path)
    assert_one_line_error(r, "cannot write", "e.gamma", "read-only")
    assert path.read_bytes() == before


def test_fmt_write_keeps_the_file_mode(tmp_path):
    path = tmp_path / "e.gamma"
    path.write_text(PATINA.read_text().replace("    s.patina", "s.patina"))
    path.chmod(0o640)
    assert run_gammac("fmt", "--write", path).returncode == 0
    assert path.stat().st_mode & 0o777 == 0o640
    assert run_gammac("fmt", "--check", path).returncode == 0


# ---- compiled-kernel cache ------------------------------------------------------------------------------


@pytest.mark.parametrize("damage", ["garbage", "truncated", "flipped", "empty", "old-format"])
def test_damaged_kernel_cache_is_rebuilt(tmp_path, damage):
    from gamma.backends.jit import JitKernels
    from gamma.frontend.checker import check as check_effect
    from gamma.frontend.parser import parse
    from test_cache import RULE, run
    from test_kernels import HEADER as KERNEL_HEADER

    effect = check_effect(parse(KERNEL_HEADER + RULE.replace("{k}", "0.5"), "c.gamma"))
    first = JitKernels(effect, cache=tmp_path)
    expected = run(first, effect)
    [path] = tmp_path.glob("*.o")
    data = path.read_bytes()
    if damage == "garbage":
        path.write_bytes(os.urandom(len(data)))
    elif damage == "truncated":
        path.write_bytes(data[: len(data) // 2])
    elif damage == "flipped":
        path.write_bytes(data[:-40] + bytes([data[-40] ^ 0xFF]) + data[-39:])
    elif damage == "empty":
        path.write_bytes(b"")
    else:                                   # machine code without the header
        from gamma.backends.jit import CACHE_MAGIC

        path.write_bytes(data[len(CACHE_MAGIC) + 4 + 64 + 32:])
    again = JitKernels(effect, cache=tmp_path)
    assert not again.from_cache
    assert run(again, effect) == expected
    assert path.read_bytes() == data            # rewritten intact
    assert JitKernels(effect, cache=tmp_path).from_cache


def rss_and_cpu(pid: int) -> tuple[int, float]:
    """Resident bytes and CPU seconds of a running process (Linux /proc)."""
    status = open(f"/proc/{pid}/status").read()
    rss = int(re.search(r"VmRSS:\s+(\d+) kB", status).group(1)) * 1024
    fields = open(f"/proc/{pid}/stat").read().rsplit(")", 1)[1].split()
    return rss, (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def test_huge_pass_runs_in_bounded_memory(tmp_path):
    """count 1e12 is within the language's limit: the pass's deposit logs are
    summed batch by batch, so memory does not grow while it traces (it grew
    by a record per surface write before), and SIGTERM stops it within a
    second with status 143."""
    (tmp_path / "e.gamma").write_text(PATINA.read_text().replace("count 4000000", "count 1e12"))
    proc = subprocess.Popen([sys.executable, "-m", "gamma.cli", "run", str(tmp_path / "e.gamma"), "--scene",
                             str(BUNNY), "--surfels", "300", "--iterations", "1", "--threads", "2",
                             "--out", str(tmp_path / "out")], stderr=subprocess.PIPE, stdout=subprocess.DEVNULL)
    try:
        seen = b""
        deadline = time.monotonic() + 300
        while b"0/1" not in seen:                          # the progress bar: tracing has begun
            assert time.monotonic() < deadline and proc.poll() is None, seen
            seen += os.read(proc.stderr.fileno(), 4096)

        def after_cpu_seconds(seconds):                    # CPU time, not wall time: the machine may be busy
            start = rss_and_cpu(proc.pid)[1]
            while True:
                rss, cpu = rss_and_cpu(proc.pid)
                if cpu >= start + seconds:
                    return rss
                assert time.monotonic() < deadline and proc.poll() is None
                time.sleep(0.2)

        rss0 = after_cpu_seconds(2)
        rss1 = after_cpu_seconds(6)                       # some million γ-tons later
        assert rss1 - rss0 < 48 << 20, (rss0, rss1)
        assert rss1 < 1 << 30
        proc.send_signal(signal.SIGTERM)
        t0 = time.monotonic()
        status = proc.wait(timeout=30)
        assert time.monotonic() - t0 < 5
        assert status == 143
        assert b"SIGTERM" in seen + proc.stderr.read()
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
