"""From LLVM IR to callable kernels: verify, optimise, JIT (or emit assembly).

The one place where llvmlite's binding layer is used.  ``JitKernels`` owns the
execution engine; it must outlive every use of the addresses it hands out
(the runtime calls them from its worker threads).  Machine code is cached on
disk, keyed by a hash of everything it depends on.
"""

from __future__ import annotations

import hashlib
from functools import lru_cache
from pathlib import Path

import llvmlite.binding as llvm
from llvmlite import ir

from .. import ownmath
from ..files import cache_dir
from ..ir.effect import Effect
from .codegen import generate


@lru_cache(maxsize=1)
def _initialise() -> None:
    llvm.initialize_native_target()
    llvm.initialize_native_asmprinter()
    ownmath.bind_into_llvm()


def target_machine():
    """A new target machine: an MCJIT engine takes ownership of the one it gets."""
    _initialise()
    target = llvm.Target.from_triple(llvm.get_process_triple())
    # Host CPU, opt level 3, but no fast-math: IR carries no fast flags and FP
    # contraction stays off, so kernels round exactly like the interpreter.
    return target.create_target_machine(cpu=llvm.get_host_cpu_name(), opt=3,
                                        codemodel="jitdefault")


def compile_ir(module: ir.Module | str, optimise: bool = True) -> llvm.ModuleRef:
    """Parse (and optimise) a module; as text, it is IR another process
    generated (``gammac run --ray`` workers), retargeted to this machine."""
    tm = target_machine()
    if isinstance(module, str):
        ref = llvm.parse_assembly(module)
        ref.triple = tm.triple
        ref.data_layout = str(tm.target_data)
    else:
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


def position_independent_object(ir_text: str) -> bytes:
    """The kernels of ``ir_text`` as a position-independent ELF object, for a
    shared object (effect_cache.py): optimised by the same pipeline for the
    same CPU as the JIT's; only the addressing differs (relocation and code
    model: PC-relative instead of absolute 64-bit addresses), not one
    arithmetic instruction."""
    _initialise()
    target = llvm.Target.from_triple(llvm.get_process_triple())
    machine = target.create_target_machine(cpu=llvm.get_host_cpu_name(), opt=3, reloc="pic",
                                           codemodel="default")
    return machine.emit_object(compile_ir(ir_text))


def assembly(module: ir.Module) -> str:
    return target_machine().emit_assembly(compile_ir(module))


def cache_key(ir_text: str) -> str:
    """Everything the machine code depends on: compiler, ABI, LLVM, host CPU, IR."""
    from .. import abi
    from ..version import version

    _initialise()
    parts = [version(), str(abi.ABI_VERSION), ".".join(map(str, llvm.llvm_version_info)),
             llvm.get_process_triple(), llvm.get_host_cpu_name(), ir_text]
    return hashlib.sha256("\0".join(parts).encode("utf-8")).hexdigest()


#: Cached object files start with this, then the ABI version (4 bytes, little
#: endian), the cache key (64 hex digits) and the SHA-256 of the machine code:
#: a truncated, corrupted or foreign file is detected and compiled again,
#: never handed to the JIT linker.
CACHE_MAGIC = b"gamma-kernels\0"


def pack_cached(key: str, code: bytes) -> bytes:
    from .. import abi

    return (CACHE_MAGIC + abi.ABI_VERSION.to_bytes(4, "little") + key.encode("ascii")
            + hashlib.sha256(code).digest() + code)


def unpack_cached(key: str, blob: bytes) -> bytes | None:
    """The machine code of a cache file, or None if it is not intact and ours."""
    from .. import abi

    head = CACHE_MAGIC + abi.ABI_VERSION.to_bytes(4, "little") + key.encode("ascii")
    if not blob.startswith(head) or len(blob) < len(head) + 32:
        return None
    digest, code = blob[len(head):len(head) + 32], blob[len(head) + 32:]
    return code if code and hashlib.sha256(code).digest() == digest else None


class JitKernels:
    """The effect's kernels compiled in this process; ``address[symbol]``.

    The machine code is cached on disk (``cache_dir()``), keyed by
    ``cache_key`` and verified on reading (``unpack_cached``): a later run
    of the same effect on the same machine skips LLVM's optimisation and code
    generation (``from_cache`` says which); a damaged cache file is replaced."""

    def __init__(self, effect: Effect, cache: Path | None | str = "default"):
        self.ir = generate(effect)
        folder = cache_dir() if cache == "default" else cache
        text = str(self.ir)
        self.llvm_version = tuple(llvm.llvm_version_info)
        key = cache_key(text)
        path = folder / f"{key}.o" if folder is not None else None
        cached = None
        if path is not None and path.is_file():
            try:
                cached = unpack_cached(key, path.read_bytes())
            except OSError:
                cached = None
            if cached is None:
                try:
                    path.unlink()
                except OSError:
                    pass
        self.from_cache = cached is not None
        self._build(effect, path, key, cached)
        # the IR as the JIT compiled it (its triple and data layout set): resume keys hash it
        self.ir_text = str(self.ir)
        if self.from_cache and not all(self.address.values()):
            self.from_cache = False           # a cached object without our symbols
            self._build(effect, path, key, None)

    def _build(self, effect: Effect, path: Path | None, key: str, cached: bytes | None) -> None:
        # With cached machine code the IR is only parsed (MCJIT takes the object).
        self.module = compile_ir(self.ir, optimise=cached is None)
        self.engine = llvm.create_mcjit_compiler(self.module, target_machine())

        def store(module, data: bytes) -> None:
            if path is None or cached is not None:
                return
            try:
                from ..files import cache_write

                cache_write(path, pack_cached(key, bytes(data)))
            except OSError:
                pass  # an unwritable cache only costs time

        self.engine.set_object_cache(store, lambda module: cached)
        self.engine.finalize_object()
        self.address = {k.symbol: self.engine.get_function_address(k.symbol)
                        for k in effect.kernels}
