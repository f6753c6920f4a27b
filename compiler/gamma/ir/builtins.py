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
``own_math``, ``random``, ``texture``); ``reference(state, call, args)``
computes it in numpy float32 (``state``: the interpreter's per-call state,
for ``random()`` and ``texture()``).  The two are written independently on
purpose: the differential tests compare them.  This module imports neither
llvmlite nor the back ends.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

from .float32 import round_f32


class _Numpy:
    """numpy, imported on first use: the checker reads this module's tables,
    and `gammac check` should not pay for numpy (only the reference
    interpreter computes with it).  The first access replaces the module
    global ``np`` with numpy itself."""

    def __getattr__(self, name):
        import numpy

        globals()["np"] = numpy
        return getattr(numpy, name)


np = _Numpy()


def f32(x):
    """numpy.float32 (the interpreter's number type); replaces itself on first call."""
    global f32
    import numpy

    f32 = numpy.float32
    return f32(x)

#: Kinds of values: numbers, truth values (comparisons), colours (rgb triples)
#: and vectors (x, y, z triples: positions, directions, SPEC §10).
KINDS = ("float", "bool", "color", "vector")
#: ``fbm(p, octaves)``: octaves is a constant whole number from 1 to this.
MAX_OCTAVES = 8


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
    string_arg: bool = False       # its one argument is a string: a file name or a name in quotes
    #: the kind of each argument (KINDS, or "octaves": a constant whole number
    #: 1 .. MAX_OCTAVES); None: every argument is a number
    args: tuple[str, ...] | None = None

    def arg_kind(self, i: int) -> str:
        return "float" if self.args is None else self.args[i]

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


def _ref_own_math(symbol):
    """The runtime's own function (``ownmath``), the one the compiled kernels call."""
    def reference(state, call, args):
        from .. import ownmath

        return f32(ownmath.function(symbol)(*[float(a) for a in args]))
    return reference


# vectors (3-tuples of float32): SPEC §11, "Vectors"

def ref_dot(a, b):
    return f32(f32(f32(a[0] * b[0]) + f32(a[1] * b[1])) + f32(a[2] * b[2]))


def ref_cross(a, b):
    return (f32(f32(a[1] * b[2]) - f32(a[2] * b[1])),
            f32(f32(a[2] * b[0]) - f32(a[0] * b[2])),
            f32(f32(a[0] * b[1]) - f32(a[1] * b[0])))


def ref_length(v):
    return f32(np.sqrt(ref_dot(v, v)))


def ref_normalize(v):
    length = ref_length(v)
    if length == 0:
        return (f32(0), f32(0), f32(0))
    return tuple(f32(c / length) for c in v)


# noise (SPEC §11, "Noise"): Perlin's improved gradient noise on the integer
# lattice, each corner's gradient from splitmix64 (abi.mix64) of its packed
# coordinates; written out here operation by operation, the code generator
# builds the same operations in LLVM IR (backends.codegen._noise_function).

#: Salt of octave 0; octave i adds i times abi.RANDOM_GOLDEN (mod 2**64).
NOISE_SALT = 0x6A09E667F3BCC909
#: Lattice coordinates are clamped to +-NOISE_CLAMP before they become integers.
NOISE_CLAMP = 2.0 ** 30
#: Each lattice coordinate enters the hash by its low NOISE_BITS bits (the
#: pattern repeats every 2**21 units along an axis).
NOISE_BITS = 21
#: The signed noise lies within +-sqrt(3)/2 (Perlin's gradients on the unit
#: cube); times this (1/sqrt(3), rounded to float32) it spans about +-0.5.
NOISE_SCALE = round_f32(1.0 / math.sqrt(3.0))


def noise_salt(octave: int) -> int:
    from ..abi import RANDOM_GOLDEN

    return (NOISE_SALT + octave * RANDOM_GOLDEN) & 0xFFFFFFFFFFFFFFFF


def _ref_fade(t):
    return f32(f32(f32(t * t) * t) * f32(f32(t * f32(f32(t * f32(6)) - f32(15))) + f32(10)))


def _ref_lerp(a, b, w):
    return f32(a + f32(w * f32(b - a)))


def ref_gradient_noise(p, octave: int):
    """The signed noise value at p (about -1 .. 1; 0 at lattice points)."""
    from ..abi import mix64

    cells, fracs = [], []
    for x in p:
        fl = f32(np.floor(x))
        with np.errstate(invalid="ignore"):     # inf - inf: NaN, as in the compiled code
            fracs.append(f32(x - fl))
        clamped = ref_pick("min", ref_pick("max", fl, f32(-NOISE_CLAMP)), f32(NOISE_CLAMP))
        cells.append(int(clamped))
    mask = (1 << NOISE_BITS) - 1
    salt = noise_salt(octave)
    corner = {}
    for cx in (0, 1):
        for cy in (0, 1):
            for cz in (0, 1):
                key = ((((cells[0] + cx) & mask) << (2 * NOISE_BITS))
                       | (((cells[1] + cy) & mask) << NOISE_BITS) | ((cells[2] + cz) & mask))
                g = mix64(key ^ salt) >> 60
                dx, dy, dz = f32(fracs[0] - f32(cx)), f32(fracs[1] - f32(cy)), f32(fracs[2] - f32(cz))
                u = dx if g < 8 else dy
                v = dy if g < 4 else dx if g in (12, 14) else dz
                corner[cx, cy, cz] = f32((-u if g & 1 else u) + (-v if g & 2 else v))
    fx, fy, fz = (_ref_fade(t) for t in fracs)
    x00 = _ref_lerp(corner[0, 0, 0], corner[1, 0, 0], fx)
    x10 = _ref_lerp(corner[0, 1, 0], corner[1, 1, 0], fx)
    x01 = _ref_lerp(corner[0, 0, 1], corner[1, 0, 1], fx)
    x11 = _ref_lerp(corner[0, 1, 1], corner[1, 1, 1], fx)
    y0 = _ref_lerp(x00, x10, fy)
    y1 = _ref_lerp(x01, x11, fy)
    return _ref_lerp(y0, y1, fz)


def _ref_unit(n):
    """Signed noise to [0, 1]: clamp(n * NOISE_SCALE + 0.5, 0, 1)."""
    return _ref_clamp(None, None, [f32(f32(n * f32(NOISE_SCALE)) + f32(0.5)), f32(0), f32(1)])


def _ref_noise(state, call, args):
    return _ref_unit(ref_gradient_noise(args[0], 0))


def fbm_weights(octaves: int) -> tuple[list[float], float]:
    """Octave i weighs 0.5**i; the sum is divided by the total (exact in float32)."""
    weights = [0.5 ** i for i in range(octaves)]
    return weights, float(sum(weights))


def _ref_fbm(state, call, args):
    p, octaves = args[0], int(args[1])
    weights, total = fbm_weights(octaves)
    acc = ref_gradient_noise(p, 0)
    for i in range(1, octaves):
        scaled = tuple(f32(c * f32(2.0 ** i)) for c in p)
        acc = f32(acc + f32(f32(weights[i]) * ref_gradient_noise(scaled, i)))
    return _ref_unit(f32(acc / f32(total)))


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


def _low_dot(emit, a, b):
    return emit.arith("+", emit.arith("+", emit.arith("*", a[0], b[0]), emit.arith("*", a[1], b[1])),
                      emit.arith("*", a[2], b[2]))


def _low_cross(emit, call, args):
    a, b = args
    return tuple(emit.arith("-", emit.arith("*", a[i], b[j]), emit.arith("*", a[j], b[i]))
                 for i, j in ((1, 2), (2, 0), (0, 1)))


def _low_length(emit, v):
    return emit.intrinsic("llvm.sqrt", [_low_dot(emit, v, v)])


def _low_normalize(emit, call, args):
    v = args[0]
    length = _low_length(emit, v)
    return tuple(emit.if_zero(length, emit.const(0.0), emit.arith("/", c, length)) for c in v)


def _low_unit(emit, n):
    return _low_clamp(emit, None, [emit.arith("+", emit.arith("*", n, emit.const(NOISE_SCALE)), emit.const(0.5)),
                                   emit.const(0.0), emit.const(1.0)])


def _low_fbm(emit, call, args):
    p, octaves = args[0], int(args[1].constant)
    weights, total = fbm_weights(octaves)
    acc = emit.gradient_noise(p, 0)
    for i in range(1, octaves):
        scaled = tuple(emit.arith("*", c, emit.const(2.0 ** i)) for c in p)
        acc = emit.arith("+", acc, emit.arith("*", emit.const(weights[i]), emit.gradient_noise(scaled, i)))
    return _low_unit(emit, emit.arith("/", acc, emit.const(total)))


def _read_from_row(*_):
    raise AssertionError("attribute() is read from the surfel row: the checker makes it a Load")


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
              (lambda symbol: lambda emit, call, args: emit.own_math(symbol, args))(symbol),
              _ref_own_math(symbol),
              ("`exp(x)`, `log(x)`, `pow(x, y)`", "gamma's own functions, the correctly rounded "
               "result but within 2^-20 ulp of a rounding boundary (§11, \"Own math\"); "
               "`log(0) = -inf`, `log(x<0) = NaN`; `pow` per C99 Annex F"))
      for name, (symbol, arity) in (("exp", ("gamma_expf", 1)), ("log", ("gamma_logf", 1)),
                                    ("pow", ("gamma_powf", 2)))),
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
    Builtin("dot", 2, 2, "float", lambda emit, call, args: _low_dot(emit, *args),
            lambda state, call, args: ref_dot(*args),
            ("`dot(a, b)`", "vectors `a`, `b`: `(a.x * b.x + a.y * b.y) + a.z * b.z`"),
            args=("vector", "vector")),
    Builtin("cross", 2, 2, "vector", _low_cross, lambda state, call, args: ref_cross(*args),
            ("`cross(a, b)`", "the vector `(a.y * b.z − a.z * b.y, a.z * b.x − a.x * b.z, "
             "a.x * b.y − a.y * b.x)`"), args=("vector", "vector")),
    Builtin("length", 1, 1, "float", lambda emit, call, args: _low_length(emit, args[0]),
            lambda state, call, args: ref_length(args[0]),
            ("`length(v)`", "`sqrt(dot(v, v))`"), args=("vector",)),
    Builtin("normalize", 1, 1, "vector", _low_normalize, lambda state, call, args: ref_normalize(args[0]),
            ("`normalize(v)`", "`v / length(v)` component by component; the zero vector (0, 0, 0) "
             "when `length(v)` is 0 (a NaN component stays NaN)"), args=("vector",)),
    Builtin("noise", 1, 1, "float", lambda emit, call, args: _low_unit(emit, emit.gradient_noise(args[0], 0)),
            _ref_noise,
            ("`noise(p)`", "gradient noise at the point `p` (a vector), in [0, 1], 0.5 at whole-number "
             "points, changing over about one unit; deterministic and the same for every run (below)"),
            args=("vector",)),
    Builtin("fbm", 2, 2, "float", _low_fbm, _ref_fbm,
            ("`fbm(p, octaves)`", f"`octaves` (a constant whole number from 1 to {MAX_OCTAVES}) of noise "
             "at doubling frequency and halving weight, in [0, 1] (below); `fbm(p, 1) = noise(p)`"),
            args=("vector", "octaves")),
    Builtin("rgb", 3, 3, "color", lambda emit, call, args: tuple(args),
            lambda state, call, args: tuple(args), None, appearance_only=True, spec_section="8a"),
    Builtin("texture", 1, 1, "color", lambda emit, call, args: emit.texture(call.texture),
            lambda state, call, args: state.texture(call), None, appearance_only=True,
            spec_section="8a", string_arg=True),
    # a mask's luminance: in appearance blocks sampled at the point like texture() (its image is
    # one of the effect's textures, luminance in every channel); in rules the checker reads the
    # surfel's value from its row (a Load), so only the appearance form is lowered here
    Builtin("mask", 1, 1, "float", lambda emit, call, args: emit.texture(call.texture)[0],
            lambda state, call, args: state.texture(call)[0],
            ('`mask("file.png")`', "the image's luminance in [0, 1] at the texture coordinates (§12a)"),
            string_arg=True),
    # a vertex attribute: always the surfel row's value (a Load), never lowered as a call
    Builtin("attribute", 1, 1, "float", _read_from_row, _read_from_row,
            ('`attribute("NAME")`', "the mesh's vertex attribute NAME interpolated at the point (§12a)"),
            string_arg=True),
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
#: A value with components is a vector (its components x, y, z); the others
#: are numbers.  Each is a field of ``abi.CONTEXT_FIELDS`` (a test checks
#: it); a vector whose field has fewer than 3 floats reads 0 for the rest.
CONTEXT_VALUES = {
    "iteration": (("transport", "update", "appearance"), ()),
    "interactions": (("transport",), ()),
    "height": (("transport", "update", "appearance"), ()),
    "position": (("transport", "update", "appearance"), ("x", "y", "z")),
    "normal": (("transport", "update", "appearance"), ("x", "y", "z")),
    "direction": (("transport",), ("x", "y", "z")),
    "up": (("transport", "update", "appearance"), ("x", "y", "z")),
    "uv": (("transport", "update", "appearance"), ("x", "y", "z")),
    "accessibility": (("transport", "update", "appearance"), ()),
    "curvature": (("transport", "update", "appearance"), ()),
}
#: Other names of components: uv.u, uv.v are uv.x, uv.y.
COMPONENT_ALIASES = {"uv": {"u": 0, "v": 1}}
#: Components of any vector value: v.x, v.y, v.z.
VECTOR_COMPONENTS = ("x", "y", "z")


def context_kind(name: str) -> str:
    """The kind of a context value: a vector or a number."""
    return "vector" if CONTEXT_VALUES[name][1] else "float"


def component_index(name: str | None, field: str) -> int | None:
    """Which component ``field`` names of a vector (the context value ``name``, or None
    for any vector), or None if it names none."""
    if field in VECTOR_COMPONENTS:
        return VECTOR_COMPONENTS.index(field)
    return COMPONENT_ALIASES.get(name or "", {}).get(field)

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
    # γ-tons leave the surfels of a surface of the effect (SPEC §6): `direction` is the axis,
    # `normal` each surfel's own; `weight` an expression of the surfel (s.NAME), per iteration
    "surface": (("surface", "surface", REQUIRED), ("direction", "axis", "normal"),
                ("emission", ("parallel", "uniform", "cosine"), "parallel"), ("weight", "weight", None)),
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
