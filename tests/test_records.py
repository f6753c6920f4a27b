"""gamma.records: the node classes' shared __eq__ and __repr__ give what
@dataclass would have generated for them.

Every node of the AST and the IR of every example and recipe is compared
with a twin made by dataclasses itself (the same fields, their repr and
compare flags kept): the same repr, and the same answers to == and != against
itself, a copy, a copy with one field changed, another class and a non-node.
"""

import copy
import dataclasses
import pickle
from pathlib import Path

import pytest

from conftest import ROOT
from gamma.frontend import ast as A
from gamma.frontend.checker import load
from gamma.frontend.parser import parse
from gamma.records import Record, record

EFFECTS = sorted((ROOT / "examples").glob("*.gamma")) + sorted((ROOT / "stdlib").glob("*.gamma"))

_twins: dict[type, type] = {}


def _twin(cls: type) -> type:
    """A plain @dataclass with the fields of ``cls`` (flags kept)."""
    if cls not in _twins:
        specs = [(f.name, f.type, dataclasses.field(repr=f.repr, compare=f.compare, init=f.init))
                 for f in dataclasses.fields(cls)]
        twin = dataclasses.make_dataclass(cls.__name__, specs)
        twin.__qualname__ = cls.__qualname__
        _twins[cls] = twin
    return _twins[cls]


def _as_twin(node):
    twin = _twin(type(node)).__new__(_twin(type(node)))
    for f in dataclasses.fields(node):
        object.__setattr__(twin, f.name, getattr(node, f.name))
    return twin


def _nodes(root):
    """Every Record reachable from ``root`` (each once)."""
    seen, stack, found = set(), [root], []
    while stack:
        x = stack.pop()
        if id(x) in seen:
            continue
        seen.add(id(x))
        if isinstance(x, Record):
            found.append(x)
            stack.extend(getattr(x, f.name) for f in dataclasses.fields(x))
        elif isinstance(x, (list, tuple)):
            stack.extend(x)
        elif isinstance(x, dict):
            stack.extend(x.values())
    return found


def _changed(node):
    """Copies of ``node``, each with one of its fields set to something else."""
    for f in dataclasses.fields(node):
        other = copy.copy(node)
        object.__setattr__(other, f.name, ("something else", getattr(node, f.name)))
        yield other, f


@pytest.mark.parametrize("path", EFFECTS, ids=lambda p: p.name)
def test_every_node_reprs_and_compares_as_its_dataclass_twin(path: Path):
    roots = [parse(path.read_text(), str(path)), load(str(path))]
    nodes = [n for root in roots for n in _nodes(root)]
    classes = {type(n) for n in nodes}
    assert {A.Module, A.Number, A.Ref} <= classes and len(classes) > 15
    for node in nodes:
        twin = _as_twin(node)
        assert repr(node) == repr(twin)
        same = copy.copy(node)
        assert (node == same, node != same) == (twin == _as_twin(same), twin != _as_twin(same)) == (True, False)
        for other, f in _changed(node):
            assert (node == other, node != other) == (twin == _as_twin(other), twin != _as_twin(other)), f.name
            assert (node != other) == f.compare
        assert node.__eq__(42) is NotImplemented and twin.__eq__(42) is NotImplemented
        assert (node == 42) is False
        with pytest.raises(TypeError):
            hash(node)


def test_a_node_of_another_class_with_the_same_fields_is_not_equal():
    a = A.Number(1.0, A.Pos(1, 1))

    @record
    class Number(Record):
        value: float
        pos: A.Pos

    b = Number(1.0, A.Pos(1, 1))
    assert repr(a) != repr(b) or type(a) is not type(b)
    assert a != b and b != a and not (a == b)


def test_fields_left_out_of_repr_and_compare_are_left_out():
    @record
    class Marked(Record):
        shown: int
        hidden: int = dataclasses.field(default=0, repr=False)
        ignored: int = dataclasses.field(default=0, compare=False)

    assert repr(Marked(1, 2, 3)).endswith("Marked(shown=1, ignored=3)")
    assert Marked(1, 2, 3) == Marked(1, 2, 4)
    assert Marked(1, 2, 3) != Marked(1, 5, 3)


def test_a_node_inside_itself_reprs_as_an_ellipsis_and_pickles():
    ref = A.Ref(["a"], A.Pos(1, 1))
    ref.part_pos.append(ref)
    assert repr(ref) == "Ref(parts=['a'], pos=Pos(line=1, col=1, width=1), part_pos=[...])"
    module = parse((ROOT / "examples" / "patina.gamma").read_text())
    assert pickle.loads(pickle.dumps(module)) == module


def test_only_a_record_subclass_is_a_record():
    with pytest.raises(TypeError, match="derives from Record"):
        @record
        class Plain:
            x: int
