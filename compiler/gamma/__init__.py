"""gamma: weathering effects by gamma-ton tracing (Chen et al., SIGGRAPH 2005).

Compiler pipeline: ``parser`` (lark) -> ``ast`` -> ``checker`` -> ``codegen``
(llvmlite IR) -> ``backend`` (verify, optimise, JIT).  ``interp`` is the
reference interpreter over the same AST.  ``runner`` drives the C++ runtime
(``gamma._runtime``); ``cli`` is the ``gammac`` command.
"""

__version__ = "0.1.0"
