"""Front end: from source text to the effect's IR (``gamma.ir``).

    parser.py       grammar loading (language/gamma.lark) and lark -> positioned AST
    ast.py          the AST: plain dataclasses with source positions
    resolve.py      name resolution: files, imports and parameters; every name
                    of a rule body bound to an ``ir.Var`` (the only lookup)
    checker.py      declarations, typing of rule bodies, the IR, warnings
    diagnostics.py  one ``Report`` of positioned errors and warnings
    fmt.py          ``gammac fmt``: the canonical layout (from lark's tree)

The front end knows nothing of LLVM, of the runtime or of output files; it
alone reports user errors in effect files.
"""
