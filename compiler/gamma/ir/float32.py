"""float32 arithmetic on Python floats without numpy: the checker's constant
folding rounds every literal and operation to float32 as the kernels would,
and `gammac check` must not pay numpy's import for it.

Rounding goes through ``struct`` (a C cast: round to nearest even, subnormals
included).  ``+ - * /`` are done in double and rounded once: for float32
operands double rounding is innocuous (53 ≥ 2·24 + 2 bits), so the result is
the correctly rounded float32 one, as numpy's float32 operations give."""

from __future__ import annotations

import math
import struct

_F32 = struct.Struct("<f")


def round_f32(x: float) -> float:
    """``x`` rounded to the nearest float32 (±inf beyond its range)."""
    try:
        return _F32.unpack(_F32.pack(x))[0]
    except OverflowError:
        return math.copysign(math.inf, x)


def arith_f32(op: str, a: float, b: float) -> float:
    """``a op b`` for op in ``+ - * /`` on float32 values, IEEE semantics
    (x/0 is ±inf, 0/0 NaN), rounded to float32."""
    a, b = round_f32(a), round_f32(b)
    if op == "+":
        r = a + b
    elif op == "-":
        r = a - b
    elif op == "*":
        r = a * b
    elif op == "/":
        if b == 0.0:
            if a == 0.0 or math.isnan(a):
                return math.nan
            return math.copysign(math.inf, a) * math.copysign(1.0, b)
        r = a / b
    else:
        raise ValueError(f"not an arithmetic operator: {op!r}")
    return round_f32(r)
