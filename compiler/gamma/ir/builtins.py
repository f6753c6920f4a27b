"""The built-in names of the language, declared once: functions, context
values and source kinds.

Each ``Builtin`` gives a function's name, its signature (argument count,
argument and result kinds, where it may be used), its LLVM lowering and its
reference semantics, and the row of language/SPEC.md that documents it.
The checker takes signatures from here, the code generator the lowering,
the reference interpreter the semantics, and a test keeps SPEC §11's table
equal to ``spec_table()``; adding a built-in is adding one entry.

``lower(emit, call, args)`` builds the value with the code generator's
emitter (``backends.codegen``: ``arith``, ``pick``, ``const``, ``intrinsic``,
``libm``, ``random``, ``texture``); ``reference(state, call, args)``
computes it in numpy float32 (``state``: the interpreter's per-call state,
for ``random()`` and ``texture()``).  The two are written independently on
purpose: the differential tests compare them.  This module imports neither
llvmlite nor the back ends.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

f32 = np.float32

#: Kinds of values: numbers, truth values (comparisons) and colours (rgb triples).
KINDS = ("float", "bool", "color")


@dataclass(frozen=True)
class Builtin:
    name: str
    min_args: int
    max_args: int | None           # None: any number from min_args
    result: str                    # a kind of KINDS, or "like-first": mix() of colours is a colour
    lower: Callable
    reference: Callable
    spec: tuple[str, str] | None   # (function, value) cells of SPEC §11's table; None: see ``spec_section``
    appearance_only: bool = False  # gives a colour: only in appearance blocks
    spec_section: str = "11"

    def accepts(self, count: int) -> bool:
        return count >= self.min_args and (self.max_args is None or count <= self.max_args)


# ---- reference semantics (numpy float32, one rounding per operation) ---------------------

def ref_arith(op: str, a, b):
    """A float32 operation; colours (3-tuples) component by component."""
    if isinstance(a, tuple) or isinstance(b, tuple):
        a = a if isinstance(a, tuple) else (a,) * 3
        b = b if isinstance(b, tuple) else (b,) * 3
        return tuple(ref_arith(op, x, y) for x, y in zip(a, b))
    return f32({"+": np.add, "-": np.subtract, "*": np.multiply, "/": np.divide}[op](a, b))


def ref_pick(name: str, a, b):
    """b if b is strictly smaller (min) / larger (max) than a, or a is NaN; else a."""
    better = b < a if name == "min" else b > a
    return f32(b if better or np.isnan(a) else a)


def _ref_fold(name):
    def fold(state, call, args):
        acc = args[0]
        for a in args[1:]:
            acc = ref_pick(name, acc, a)
        return acc
    return fold


def _ref_clamp(state, call, args):
    return ref_pick("min", ref_pick("max", args[0], args[1]), args[2])


def _ref_smoothstep(state, call, args):
    e0, e1, x = args
    t = _ref_clamp(state, call, [f32(f32(x - e0) / f32(e1 - e0)), f32(0), f32(1)])
    return f32(f32(t * t) * f32(f32(3) - f32(f32(2) * t)))


_LIBM: dict = {}


def libm(name: str) -> Callable:
    """The C library's expf/logf/powf, which the compiled kernels call too
    (numpy's own float32 exp/log differ from libm in the last bit)."""
    if not _LIBM:
        import ctypes
        import ctypes.util

        lib = ctypes.CDLL(ctypes.util.find_library("m"))
        for fname, arity in (("expf", 1), ("logf", 1), ("powf", 2)):
            fn = getattr(lib, fname)
            fn.restype = ctypes.c_float
            fn.argtypes = [ctypes.c_float] * arity
            _LIBM[fname] = fn
    return _LIBM[name]


def _ref_libm(name):
    return lambda state, call, args: f32(libm(name)(*[float(a) for a in args]))


# ---- LLVM lowering (through the code generator's emitter) -----------------------------------

def _low_fold(name):
    def fold(emit, call, args):
        acc = args[0]
        for a in args[1:]:
            acc = emit.pick(name, acc, a)
        return acc
    return fold


def _low_clamp(emit, call, args):
    return emit.pick("min", emit.pick("max", args[0], args[1]), args[2])


def _low_smoothstep(emit, call, args):
    e0, e1, x = args
    t = _low_clamp(emit, call, [emit.arith("/", emit.arith("-", x, e0), emit.arith("-", e1, e0)),
                                emit.const(0.0), emit.const(1.0)])
    return emit.arith("*", emit.arith("*", t, t),
                      emit.arith("-", emit.const(3.0), emit.arith("*", emit.const(2.0), t)))


def _low_mix(emit, call, args):
    a, b, t = args
    return emit.arith("+", a, emit.arith("*", emit.arith("-", b, a), t))


BUILTINS: tuple[Builtin, ...] = (
    Builtin("min", 2, None, "float", _low_fold("min"), _ref_fold("min"),
            ("`min(a, b, …)`", "≥ 2 arguments, folded left: `pick(pick(a, b), c)`, where "
             "`pick(a, b)` = `b` if `b < a` or `a` is NaN, else `a`")),
    Builtin("max", 2, None, "float", _low_fold("max"), _ref_fold("max"),
            ("`max(a, b, …)`", "likewise with `b > a`")),
    Builtin("clamp", 3, 3, "float", _low_clamp, _ref_clamp,
            ("`clamp(x, lo, hi)`", "`min(max(x, lo), hi)`; if `lo > hi` the result is `hi`; "
             "`clamp(NaN, lo, hi)` = `min(lo, hi)`")),
    Builtin("mix", 3, 3, "like-first", _low_mix,
            lambda state, call, args: ref_arith("+", args[0], ref_arith("*", ref_arith("-", args[1], args[0]),
                                                                        args[2])),
            ("`mix(a, b, t)`", "`a + (b − a) * t`")),
    Builtin("smoothstep", 3, 3, "float", _low_smoothstep, _ref_smoothstep,
            ("`smoothstep(e0, e1, x)`", "`t = clamp((x − e0) / (e1 − e0), 0, 1)`, then "
             "`(t * t) * (3 − 2 * t)`; with `e0 = e1`: 1 for `x > e0`, else 0")),
    Builtin("abs", 1, 1, "float", lambda emit, call, args: emit.intrinsic("llvm.fabs", args),
            lambda state, call, args: f32(np.abs(args[0])),
            ("`abs(x)`", "`|x|` (clears the sign bit)")),
    Builtin("sqrt", 1, 1, "float", lambda emit, call, args: emit.intrinsic("llvm.sqrt", args),
            lambda state, call, args: f32(np.sqrt(args[0])),
            ("`sqrt(x)`", "IEEE square root (NaN for `x < 0`, `sqrt(-0) = -0`)")),
    *(Builtin(name, arity, arity, "float",
              (lambda fname: lambda emit, call, args: emit.libm(fname, args))(name + "f"),
              _ref_libm(name + "f"),
              ("`exp(x)`, `log(x)`, `pow(x, y)`", "the C library's `expf`, `logf`, `powf` "
               "(`log(0) = -inf`, `log(x<0) = NaN`; `pow` per C99 Annex F)"))
      for name, arity in (("exp", 1), ("log", 1), ("pow", 2))),
    Builtin("floor", 1, 1, "float", lambda emit, call, args: emit.intrinsic("llvm.floor", args),
            lambda state, call, args: f32(np.floor(args[0])),
            ("`floor(x)`", "largest integer ≤ `x`")),
    Builtin("fract", 1, 1, "float",
            lambda emit, call, args: emit.arith("-", args[0], emit.intrinsic("llvm.floor", args)),
            lambda state, call, args: f32(args[0] - np.floor(args[0])),
            ("`fract(x)`", "`x − floor(x)` (in [0, 1) for moderate `x`; rounding can give exactly "
             "1 for tiny negative `x`)")),
    Builtin("random", 0, 0, "float", lambda emit, call, args: emit.random(call.site),
            lambda state, call, args: state.random(call),
            ("`random()`", "a number in [0, 1) with 24 random bits, deterministic (below)")),
    Builtin("rgb", 3, 3, "color", lambda emit, call, args: tuple(args),
            lambda state, call, args: tuple(args), None, appearance_only=True, spec_section="8a"),
    Builtin("texture", 1, 1, "color", lambda emit, call, args: emit.texture(call.texture),
            lambda state, call, args: state.texture(call), None, appearance_only=True,
            spec_section="8a"),
    # the scene's own colour: the slot after the effect's textures (``Call.texture``, set by the checker)
    Builtin("base_color", 0, 0, "color", lambda emit, call, args: emit.texture(call.texture),
            lambda state, call, args: state.texture(call), None, appearance_only=True,
            spec_section="8a"),
)

FUNCTIONS: dict[str, Builtin] = {b.name: b for b in BUILTINS}


def spec_table() -> str:
    """SPEC §11's table of built-in functions, as the table above gives it."""
    rows = ["| function | value |", "|---|---|"]
    for b in BUILTINS:
        if b.spec is not None:
            row = f"| {b.spec[0]} | {b.spec[1]} |"
            if row != rows[-1]:    # exp, log and pow share a row
                rows.append(row)
    return "\n".join(rows)


#: Read-only context values: name -> (rules that may read them, components).
#: Each is a field of ``abi.CONTEXT_FIELDS`` (a test checks it).
CONTEXT_VALUES = {
    "iteration": (("transport", "update", "appearance"), ()),
    "interactions": (("transport",), ()),
    "height": (("transport", "update", "appearance"), ()),
    "position": (("transport", "update", "appearance"), ("x", "y", "z")),
    "normal": (("transport", "update", "appearance"), ("x", "y", "z")),
    "direction": (("transport",), ("x", "y", "z")),
    "uv": (("appearance",), ("u", "v")),
}

REQUIRED = object()
#: Source kinds of the language: their parameters in positional order,
#: (name, type, default).  ``area`` and ``environment`` become the runtime
#: kind their ``shape`` names; every runtime kind is one of
#: ``abi.SOURCE_KINDS`` (a test checks the two agree).
SOURCE_PARAMS = {
    "point": (("position", "place", REQUIRED),),
    "spot": (("position", "place", REQUIRED), ("direction", "direction", "down"),
             ("angle", "angle", REQUIRED), ("falloff", "nonnegative", 0.0)),
    "area": (("shape", ("rect", "disk"), REQUIRED), ("position", "place", REQUIRED),
             ("normal", "direction", "down"), ("size", "size2", None), ("radius", "length", None),
             ("emission", ("parallel", "uniform", "cosine"), "parallel")),
    "directional": (("direction", "direction", "down"),),
    "environment": (("shape", ("sphere", "hemisphere"), REQUIRED),),
}
SOURCE_KINDS = tuple(SOURCE_PARAMS)
#: The language kinds whose ``shape`` argument is the runtime's kind.
SHAPED_KINDS = ("area", "environment")


def runtime_source_kinds() -> tuple[str, ...]:
    """Every runtime kind a source of the language can become, in table order."""
    kinds = []
    for kind, params in SOURCE_PARAMS.items():
        kinds += list(dict(((n, t) for n, t, _ in params))["shape"]) if kind in SHAPED_KINDS else [kind]
    return tuple(kinds)
