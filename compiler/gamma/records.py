"""``record``: a ``@dataclass`` whose ``__eq__`` and ``__repr__`` are shared.

``@dataclass`` writes each method it adds as source text and compiles it
when the class is defined: ``__init__``, ``__repr__`` and ``__eq__``, three
compilations per class.  The AST's and the IR's ~50 node classes and the
driver's few records cost every ``gammac`` command ~30-50 ms of start-up
that way (a rerun whose effect comes from the cache included: unpickling it
imports both modules).  A ``record`` keeps the generated ``__init__`` (nodes
are made by the thousand while parsing) and takes ``__eq__`` and
``__repr__`` from ``Record``, which work out the same results from the
class's fields: equal when of the same class and the fields that compare
are equal as a tuple, ``Name(field=value, ...)`` for the fields shown, ``...``
for a node inside itself.  As with ``@dataclass(eq=True)``, instances are
unhashable.  Frozen dataclasses stay plain ``@dataclass(frozen=True)`` (their
generated ``__setattr__`` and ``__hash__`` are what makes them frozen).
"""

from __future__ import annotations

import reprlib
from dataclasses import dataclass, fields

_compared: dict[type, tuple[str, ...]] = {}
_shown: dict[type, tuple[str, ...]] = {}


def _names(cls: type, table: dict, flag: str) -> tuple[str, ...]:
    names = table.get(cls)
    if names is None:
        names = table[cls] = tuple(f.name for f in fields(cls) if getattr(f, flag))
    return names


class Record:
    """Base of the classes ``record`` makes: ``__eq__`` and ``__repr__`` as
    ``@dataclass`` would generate them for the subclass."""

    __slots__ = ()

    def __eq__(self, other):
        if other.__class__ is not self.__class__:
            return NotImplemented
        names = _names(self.__class__, _compared, "compare")
        return tuple(getattr(self, n) for n in names) == tuple(getattr(other, n) for n in names)

    __hash__ = None     # mutable and compared by value, as a @dataclass with eq=True

    @reprlib.recursive_repr()
    def __repr__(self) -> str:
        shown = ", ".join(f"{n}={getattr(self, n)!r}" for n in _names(self.__class__, _shown, "repr"))
        return f"{self.__class__.__qualname__}({shown})"


def record(cls: type) -> type:
    """``@dataclass`` for a subclass of ``Record``: only ``__init__`` is generated."""
    if not issubclass(cls, Record):
        raise TypeError(f"{cls.__qualname__}: a record derives from Record")
    return dataclass(cls, eq=False, repr=False)
