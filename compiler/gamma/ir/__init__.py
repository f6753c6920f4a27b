"""The IR: one typed, resolved description of an effect between the front
end and the back ends.

``effect`` holds the data types (declarations, kernels, rule bodies with
every name bound) and ``dump``; ``builtins`` declares the language's
built-in functions (signature, LLVM lowering, reference semantics), context
values and source kinds once.  Nothing here parses, checks or generates code.
"""
