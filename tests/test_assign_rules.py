"""--assign rules: the first rule whose pattern matches a triangle's object,
group or material name or its file's name wins; a rule beaten to every
triangle it names is reported (the file-name trap: 'arch=...' matches every
part of arch.obj)."""

from gamma.driver.running.scene import load_scene
from gamma.frontend.checker import load

EFFECT = """\
ton Sand { motion straight = 0.5 carry grit = 1 }
surface Sandstone { property worn = 0 }
surface Ground { property worn = 0 }
source wind = environment(sphere) emits Sand count 1000
on settle(t: Sand, s: *) { s.worn += 0.01 * t.grit }
"""

OBJ = """\
o arch
v 0 0 0
v 1 0 0
v 0 1 0
f 1 2 3
o ground
v 0 0 1
v 1 0 1
v 0 0 2
f 4 5 6
"""


def _scene(rt, tmp_path, rules):
    (tmp_path / "arch.obj").write_text(OBJ)
    (tmp_path / "erode.gamma").write_text(EFFECT)
    effect = load(str(tmp_path / "erode.gamma"))
    return load_scene(rt, str(tmp_path / "arch.obj"), effect, rules)


def test_a_rule_beaten_through_the_file_name_is_reported(rt, tmp_path, capsys):
    scene = _scene(rt, tmp_path, ["arch=Sandstone", "ground=Ground"])
    assert scene.triangles_per_surface == {"Sandstone": 2, "Ground": 0}   # the file name 'arch' took both
    err = capsys.readouterr().err
    assert "warning: --assign ground=Ground is never used" in err
    assert "arch=Sandstone" in err and "'arch'" in err


def test_the_narrower_rule_first_binds_each_part_without_a_warning(rt, tmp_path, capsys):
    scene = _scene(rt, tmp_path, ["ground=Ground", "arch=Sandstone"])
    assert scene.triangles_per_surface == {"Sandstone": 1, "Ground": 1}
    assert "warning" not in capsys.readouterr().err


def test_a_rule_that_wins_somewhere_is_not_reported(rt, tmp_path, capsys):
    _scene(rt, tmp_path, ["ground=Ground", "*=Sandstone", "gr*=Sandstone"])
    err = capsys.readouterr().err
    assert "gr*=Sandstone is never used" in err          # beaten on 'ground' by the first rule
    assert "*=Sandstone is never used" not in err.replace("gr*=Sandstone", "")
