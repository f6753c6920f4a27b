"""Back ends: what executes an effect's rules.

``codegen`` lowers the checked effect to LLVM IR (one C-ABI function per
kernel, signatures from ``gamma.abi``); ``jit`` verifies, optimises and
JIT-compiles it (or prints assembly) and caches machine code; ``interp`` is
the reference interpreter, the oracle compiled kernels are tested against.

Back ends read the checked effect; they never parse, resolve or report user
errors (anything they meet is a compiler bug).
"""
