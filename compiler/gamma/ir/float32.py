"""float32 rounding of Python floats without numpy.

The checker folds constants in float32 as the compiled kernels compute them;
doing it with ``struct`` keeps numpy out of ``gammac check``'s start-up.
"""

from __future__ import annotations

import math
import struct

_FLOAT32 = struct.Struct("<f")


def f32(value: float) -> float:
    """``value`` rounded to the nearest float32 (an infinity beyond its range),
    as ``numpy.float32(value)``."""
    try:
        return _FLOAT32.unpack(_FLOAT32.pack(value))[0]
    except OverflowError:
        return math.copysign(math.inf, value)


def fold(op: str, a: float, b: float) -> float:
    """``a op b`` for float32 operands, rounded once to float32, as the machine
    would (IEEE: ±inf or NaN instead of an error).  Computed in double and
    rounded: a double carries more than twice float32's precision, so for
    + - * / the twice-rounded result is the correctly rounded one."""
    a, b = f32(a), f32(b)
    if op == "+":
        r = a + b
    elif op == "-":
        r = a - b
    elif op == "*":
        r = a * b
    elif op == "/":
        if b == 0.0:
            r = math.nan if a == 0.0 or math.isnan(a) else math.copysign(math.inf, a) * math.copysign(1.0, b)
        else:
            r = a / b
    else:
        raise ValueError(f"no float32 operation {op!r}")
    return f32(r)
