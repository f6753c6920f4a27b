"""The project's own float math (runtime/src/gmath.cpp, SPEC §11): ``exp``,
``log``, ``pow`` (and ``sin``, ``cos``, ``tan``, ``atan2``) as C functions of
the runtime extension.  The compiled kernels call them by these symbols (the
JIT binds each to its address, ``bind_into_llvm``; the effect cache's shared
objects find them in the extension, ``make_global``) and the reference
interpreter calls the same functions through ctypes (``function``), so both
give the same bits on every machine, whatever its C library.

Imports the runtime extension on first use only (the checker and the code
generator do not need it).
"""

from __future__ import annotations

import ctypes
import os
from functools import lru_cache
from typing import Callable

#: language name -> (C symbol, arity)
FUNCTIONS: dict[str, tuple[str, int]] = {
    "exp": ("gamma_expf", 1),
    "log": ("gamma_logf", 1),
    "pow": ("gamma_powf", 2),
}


@lru_cache(maxsize=1)
def addresses() -> dict[str, int]:
    """C symbol -> address of every function of the runtime's own math."""
    from . import _runtime

    return {str(k): int(v) for k, v in _runtime.MATH_FUNCTIONS.items()}


@lru_cache(maxsize=None)
def function(symbol: str) -> Callable:
    """The runtime's own ``symbol`` (e.g. ``gamma_expf``) as a Python callable
    of floats."""
    arity = {"gamma_atan2f": 2, "gamma_powf": 2}.get(symbol, 1)
    prototype = ctypes.CFUNCTYPE(ctypes.c_float, *[ctypes.c_float] * arity)
    return prototype(addresses()[symbol])


@lru_cache(maxsize=1)
def bind_into_llvm() -> None:
    """Make the JIT resolve the kernels' calls of the own math (once a process)."""
    import llvmlite.binding as llvm

    for symbol, address in addresses().items():
        llvm.add_symbol(symbol, address)


@lru_cache(maxsize=1)
def make_global() -> None:
    """Give the runtime extension's symbols global scope, so that a shared
    object of kernels loaded later (the effect cache's) resolves its calls of
    the own math to the extension that is already loaded (dlopen with
    RTLD_NOLOAD only changes its flags)."""
    from . import _runtime

    ctypes.CDLL(_runtime.__file__, mode=os.RTLD_NOLOAD | os.RTLD_GLOBAL)
