"""Back ends: what executes an effect's IR.

    codegen.py  IR -> LLVM IR (one C-ABI function per kernel, signatures from
                ``gamma.abi``, built-ins lowered by ``ir.builtins``)
    jit.py      verify -> optimise -> JIT (MCJIT), or assembly; machine-code cache
    interp.py   the reference interpreter: an independent reading of the IR by
                names (not slots), the oracle compiled kernels are tested against

Back ends read the IR only: they never parse, look names up or report user
errors (anything they meet is a compiler bug).  ``gammac emit --effect | --ir
| --ir-opt | --asm`` prints each stage.
"""
