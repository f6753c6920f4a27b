"""Front end: from source text to a checked effect.

``parser`` (grammar loading, lark) builds the positioned AST of ``ast``;
``checker`` resolves names, types and checks it and produces the effect the
back ends and the driver consume; ``diagnostics`` collects positioned
messages and prints them; ``fmt`` prints the canonical layout of a file.

The front end knows nothing of LLVM, of the runtime or of output files.
"""
