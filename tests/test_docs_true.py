"""What the documentation states about the code is checked against the code:
the ABI version, the keywords and declarations of the grammar, the paths
`--export` names in its help."""

import re

from conftest import ROOT, run_gammac

SPEC = (ROOT / "language" / "SPEC.md").read_text(encoding="utf-8")
GRAMMAR = (ROOT / "language" / "gamma.lark").read_text(encoding="utf-8")


def test_spec_states_the_abi_version_of_the_code():
    from gamma import abi

    assert re.search(r"kernel ABI (\d+)", SPEC).group(1) == str(abi.ABI_VERSION)


def test_spec_keyword_list_is_the_grammars():
    listed = re.search(r"\*\*Keywords\*\* `([^`]*)`", SPEC).group(1).split()
    assert sorted(listed) == sorted(set(re.findall(r'"([a-z]+)"', GRAMMAR)))


def test_spec_declaration_rule_is_the_grammars():
    def alternatives(text):
        rule = re.search(r"\?decl:(.*?)(?:\n\n|\n```|\n[a-z/])", text, re.S).group(1)
        return sorted(a.strip() for a in rule.split("|"))

    assert alternatives(SPEC) == alternatives(GRAMMAR)


def test_spec_resync_keywords_are_the_parsers():
    from gamma.frontend.parser import _DECL_START

    resync = re.search(r"a line starting with `([^`]*)`", SPEC).group(1).split()
    assert sorted(resync) == sorted(_DECL_START.pattern.split("(")[1].split(")")[0].split("|"))


def test_export_help_names_the_real_paths():
    r = run_gammac("run", "--help")
    text = " ".join(r.stdout.split())
    assert "DIR/export/SCENE_NNNN.glb" in text
