"""From LLVM IR to callable kernels: verify, optimise, JIT (or emit assembly).

The one place where llvmlite's binding layer is used.  ``JitKernels`` owns the
execution engine; it must outlive every use of the addresses it hands out
(the runtime calls them from its worker threads).
"""

from __future__ import annotations

from functools import lru_cache

import llvmlite.binding as llvm
from llvmlite import ir

from .checker import Effect
from .codegen import generate


@lru_cache(maxsize=1)
def _initialise() -> None:
    llvm.initialize_native_target()
    llvm.initialize_native_asmprinter()


def _target_machine():
    """A new target machine: an MCJIT engine takes ownership of the one it gets."""
    _initialise()
    target = llvm.Target.from_triple(llvm.get_process_triple())
    # Host CPU, opt level 3, but no fast-math: IR carries no fast flags and FP
    # contraction stays off, so kernels round exactly like the interpreter.
    return target.create_target_machine(cpu=llvm.get_host_cpu_name(), opt=3,
                                        codemodel="jitdefault")


def compile_ir(module: ir.Module, optimise: bool = True) -> llvm.ModuleRef:
    tm = _target_machine()
    module.triple = tm.triple
    module.data_layout = str(tm.target_data)
    ref = llvm.parse_assembly(str(module))
    ref.verify()
    if optimise:
        pto = llvm.create_pipeline_tuning_options(speed_level=3)
        pb = llvm.create_pass_builder(tm, pto)
        pb.getModulePassManager().run(ref, pb)
        ref.verify()
    return ref


def assembly(module: ir.Module) -> str:
    return _target_machine().emit_assembly(compile_ir(module))


class JitKernels:
    """The effect's kernels compiled in this process; ``address[symbol]``."""

    def __init__(self, effect: Effect):
        self.ir = generate(effect)
        self.module = compile_ir(self.ir)
        self.engine = llvm.create_mcjit_compiler(self.module, _target_machine())
        self.engine.finalize_object()
        self.address = {k.symbol: self.engine.get_function_address(k.symbol)
                        for k in effect.kernels}
