"""gamma: weathering effects by gamma-ton tracing (Chen et al., SIGGRAPH 2005).

    frontend/   source text -> AST -> names bound -> typed IR; diagnostics; formatter
    ir/         the IR of an effect, and the built-ins declared once
    backends/   LLVM code generation + verify/optimise/JIT; reference interpreter
    driver/     the run loop over the C++ runtime (``gamma._runtime``), its
                writers (maps, renders, summary, export), scene loading
    abi.py      the compiler <-> runtime interface, declared once
    files.py    atomic file writes
    cli.py      the ``gammac`` command

Dependencies point one way: cli -> driver -> backends -> ir <- frontend; all -> abi.
"""

__version__ = "0.1.0"
