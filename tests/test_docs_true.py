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


def test_spec_lists_every_run_option_with_its_default():
    """SPEC §16.1's table of `run` options has a row per option of
    options.OPTIONS that `gammac run` takes, with its default."""
    from gamma.options import OPTIONS, REQUIRED

    cell = r"((?:[^|\\]|\\.)*)"            # a table cell (a pipe in it is written \|)
    pattern = r"^\| `(--[a-z-]+)" + cell + r"\| " + cell + r" \|"
    rows = {m.group(1): m.group(3) for m in re.finditer(pattern, SPEC, re.M)}
    for o in OPTIONS:
        if o.flag is None or o.group == "api":
            continue
        assert o.flag in rows, f"SPEC §16.1 has no row for {o.flag}"
        if isinstance(o.default, (int, float)) and not isinstance(o.default, bool) and o.default is not REQUIRED:
            assert rows[o.flag].startswith(f"{o.default:g}"), (o.flag, rows[o.flag])
