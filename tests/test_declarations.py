"""Interfaces declared once stay in step with what they describe: the
built-in table with SPEC §11, context values and source kinds with the ABI,
the ABI's binding with the runtime module; and the reference interpreter is
an independent reading (a front-end slot bug cannot pass unseen)."""

import ctypes
import dataclasses
import re
import types

import numpy as np
import pytest

from conftest import ROOT
from gamma import abi
from gamma.backends.interp import Context, run_kernel
from gamma.backends.jit import JitKernels
from gamma.frontend.checker import check, load
from gamma.frontend.parser import parse
from gamma.ir import effect as ir
from gamma.ir.builtins import BUILTINS, CONTEXT_VALUES, runtime_source_kinds, spec_table
from test_kernels import HEADER, TRANSPORT, GammaContext, ptr

SPEC = (ROOT / "language" / "SPEC.md").read_text(encoding="utf-8")


def section(number: str) -> str:
    start = SPEC.index(f"\n## {number} ")
    return SPEC[start:SPEC.index("\n## ", start + 1)]


def test_spec_section_11_table_is_the_builtin_table():
    table = "\n".join(line for line in section("11").splitlines() if line.startswith("|"))
    assert table == spec_table()


def test_every_builtin_is_documented_where_the_table_says():
    for b in BUILTINS:
        if b.spec is None:
            assert f"`{b.name}(" in section(b.spec_section), b.name
        assert b.spec_section in ("11", "8a")


def test_context_values_are_context_fields():
    fields = {name: count for name, _, count in abi.CONTEXT_FIELDS}
    for name, (_, components) in CONTEXT_VALUES.items():
        if components:   # a vector: x, y, z; a field of 2 floats (uv) reads z = 0
            assert components == ("x", "y", "z") and fields[name] in (2, 3), name
        else:
            assert fields[name] == 1, name


def test_source_kinds_of_the_language_are_the_runtime_kinds():
    assert runtime_source_kinds() == abi.SOURCE_KINDS


def test_the_runtime_knows_exactly_the_abi_source_kinds(rt, bumpy_obj):
    from gamma.driver.running.runner import RunOptions, build_config

    effect = load(str(ROOT / "examples" / "patina.gamma"))
    mesh = rt.Mesh.load(str(bumpy_obj))
    jit = JitKernels(effect)
    cfg = build_config(rt, effect, jit, RunOptions(scene="", out="", surfels=200), mesh.bounds,
                       (0.0, -1.0, 0.0))
    cfg.triangle_surface = np.zeros(mesh.num_triangles, np.int32)
    with pytest.raises((ValueError, RuntimeError)) as err:
        cfg.add_source("nonsense", 0, 1)
        rt.Simulation(mesh, cfg)
    listed = re.search(r"expected ([a-z, ]+)", str(err.value)).group(1)
    assert tuple(listed.replace(" or ", ", ").split(", ")) == abi.SOURCE_KINDS


def test_the_binding_matches_the_runtime(rt):
    assert abi.check_runtime(rt) == []
    fake = types.SimpleNamespace(ABI_VERSION=abi.ABI_VERSION - 1, Mesh=rt.Mesh, Config=object,
                                 Simulation=rt.Simulation)
    problems = abi.check_runtime(fake)
    assert problems[0] == f"runtime ABI {abi.ABI_VERSION - 1} does not match compiler ABI {abi.ABI_VERSION}"
    assert any(p.startswith("the module lacks RUNTIME_VERSION, EMBREE_VERSION") for p in problems)
    assert any(p.startswith("Config lacks surfels, seed") for p in problems)


def test_statement_numbers_and_random_sites_come_from_the_ir():
    effect = check(parse(HEADER + "on hit(t: T, s: S) { t.a = random()\n if t.a < 1 { t.b = random() }"
                                  "\n s.p += random() }", "n.gamma"))
    kernel = effect.kernels[0]
    assert [st.number for st in kernel.statements()] == [1, 2, 3]
    assert [st.value.site if isinstance(st.value, ir.Call) else st.value.right.site
            for st in kernel.statements()] == [0, 1, 2]
    assert kernel.random_sites == 3


def _swap_slots(kernel, a: str, b: str):
    """A front-end bug: the slots of surface properties a and b exchanged in the IR."""
    def fix(node):
        if isinstance(node, list):
            return [fix(n) for n in node]
        if isinstance(node, ir.Var) and node.space == "surf" and node.name in (a, b):
            other = kernel.surface.properties[b if node.name == a else a]
            return dataclasses.replace(node, slot=other)
        if dataclasses.is_dataclass(node) and not isinstance(node, (ir.Var, ir.TonType, ir.Surface)):
            return dataclasses.replace(node, **{f.name: fix(getattr(node, f.name))
                                                for f in dataclasses.fields(node)
                                                if f.name not in ("pos",)})
        return node
    kernel.bodies = fix(kernel.bodies)


def test_a_slot_bug_in_the_front_end_shows_as_a_difference():
    source = HEADER + "on hit(t: T, s: S) { s.p += t.a * 2\n s.q += t.b }"
    surf = np.array([0.25, 0, 0, 3, 4], np.float32)

    def both(effect):
        kernel = effect.kernels[0]
        jit = JitKernels(effect, cache=None)
        ton = np.array([1.5, -2], np.float32)
        compiled, interpreted = np.zeros(5, np.float32), np.zeros(5, np.float32)
        TRANSPORT(jit.address[kernel.symbol])(ptr(ton.copy()), ptr(surf.copy()), ptr(compiled),
                                               ctypes.byref(GammaContext()))
        run_kernel(kernel, ton.copy(), surf.copy(), interpreted, Context())
        return compiled, interpreted

    compiled, interpreted = both(check(parse(source, "ok.gamma")))
    assert list(compiled) == list(interpreted) == [0, 0, 0, 3, -2]
    broken = check(parse(source, "bug.gamma"))
    _swap_slots(broken.kernels[0], "p", "q")
    compiled, interpreted = both(broken)
    assert list(interpreted) == [0, 0, 0, 3, -2]      # the interpreter reads names, not slots
    assert list(compiled) == [0, 0, 0, -2, 3]         # the code generator followed the bad slots


def test_spec_lists_the_abi_statistics_in_order():
    summary = SPEC[SPEC.index("iterations: [ {"):SPEC.index("property_sums: {PROP")]
    listed = re.findall(r"[a-z_]+", summary.removeprefix("iterations: [ {"))
    assert tuple(listed) == abi.STATISTICS
