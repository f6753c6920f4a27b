"""The live viewer of ``gammac watch``: ``watch`` (the re-run loop),
``server`` (HTTP on 127.0.0.1, server-sent events) and ``static/`` (the
page, with three.js vendored in at build time from web/node_modules)."""
