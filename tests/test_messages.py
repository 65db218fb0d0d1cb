"""Every check, error class and message line of the code has its entry in ``dualcal.messages`` (the page
*Checks and messages*), found from the code itself, not from a second list: a new check cannot ship without
its page. The commands' ``--help`` and error lines name their pages."""

from __future__ import annotations

import ast
import functools
import re
from pathlib import Path

import pytest

import dualcal
from dualcal import messages

PACKAGE = Path(dualcal.__file__).parent
DOCS = PACKAGE.parents[1] / "docs"


@functools.lru_cache
def _sources(package: Path = PACKAGE) -> list[tuple[Path, ast.Module]]:
    """Every module of ``package`` but this table itself, parsed once."""
    return [(path, ast.parse(path.read_text(encoding="utf-8"))) for path in sorted(package.rglob("*.py"))
            if path.name != "messages.py"]


def _is_checks(node) -> bool:
    """``checks`` or ``<anything>.checks``: where a calibration's checks are kept."""
    return (isinstance(node, ast.Name) and node.id == "checks") or (isinstance(node, ast.Attribute)
                                                                     and node.attr == "checks")


def _keys(node) -> set[str]:
    if isinstance(node, ast.Dict):
        return {k.value for k in node.keys if isinstance(k, ast.Constant) and isinstance(k.value, str)}
    if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id == "dict":
        return {k.arg for k in node.keywords if k.arg}
    return set()


def check_names_in_code(package: Path = PACKAGE) -> set[str]:
    """Every name the code writes into a calibration's checks: ``checks["x"] = ...``, ``rig.checks["x"] =
    ...``, ``checks = {"x": ...}``, ``checks.update({...})``, ``checks.setdefault("x", ...)``."""
    names = set()
    for _, tree in _sources(package):
        for node in ast.walk(tree):
            if isinstance(node, (ast.Assign, ast.AnnAssign, ast.AugAssign)):
                targets = node.targets if isinstance(node, ast.Assign) else [node.target]
                for target in targets:
                    if isinstance(target, ast.Subscript) and _is_checks(target.value) \
                            and isinstance(target.slice, ast.Constant) and isinstance(target.slice.value, str):
                        names.add(target.slice.value)
                    elif _is_checks(target) and node.value is not None:
                        names |= _keys(node.value)
            elif isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and _is_checks(node.func.value):
                if node.func.attr == "update" and node.args:
                    names |= _keys(node.args[0])
                elif node.func.attr == "setdefault" and node.args and isinstance(node.args[0], ast.Constant):
                    names.add(node.args[0].value)
    return names


def error_classes_in_code(package: Path = PACKAGE) -> set[str]:
    """Every public class that derives, through any of dualcal's classes, from ``DualcalError``."""
    bases = {}
    for _, tree in _sources(package):
        for node in ast.walk(tree):
            if isinstance(node, ast.ClassDef):
                bases[node.name] = {b.id if isinstance(b, ast.Name) else getattr(b, "attr", "") for b in node.bases}
    errors, grown = {"DualcalError"}, True
    while grown:
        new = {name for name, parents in bases.items() if parents & errors} - errors
        errors |= new
        grown = bool(new)
    return {name for name in errors if not name.startswith("_")}


def _strings(package: Path = PACKAGE):
    """Every string of the code, an f-string's text parts joined by ``{}``."""
    for _, tree in _sources(package):
        for node in ast.walk(tree):
            if isinstance(node, ast.Constant) and isinstance(node.value, str):
                yield node.value
            elif isinstance(node, ast.JoinedStr):
                yield "{}".join(v.value if isinstance(v, ast.Constant) else "" for v in node.values)


def line_kinds_in_code(package: Path = PACKAGE) -> set[str]:
    """The kinds of ``dualcal: KIND: ...`` line the code prints (markup such as ``[yellow]`` dropped)."""
    kinds = set()
    for text in _strings(package):
        for m in re.finditer(r"dualcal: ([a-z][a-z ]*?)(?::|$|\[)", re.sub(r"\[/?[a-z ]*\]", "", text)):
            kinds.add(m.group(1))
    return kinds


def test_every_check_the_code_writes_has_its_entry():
    names = check_names_in_code()
    assert {"converged", "rig_rigid", "loop_closure"} <= names          # the finder finds what is there
    assert not names - set(messages.CHECKS), f"checks without an entry in dualcal.messages.CHECKS: " \
                                             f"{sorted(names - set(messages.CHECKS))}"


def test_every_entry_is_a_check_the_code_writes():
    """No entry for a check that no longer exists (renamed or removed)."""
    assert not set(messages.CHECKS) - check_names_in_code()


def test_every_error_class_has_its_entry():
    classes = error_classes_in_code()
    assert {"InputError", "EstimationError", "DetectionError", "OutputError"} <= classes
    assert not classes - set(messages.ERRORS), sorted(classes - set(messages.ERRORS))
    assert not set(messages.ERRORS) - classes


def test_every_kind_of_line_the_command_prints_has_its_entry():
    kinds = line_kinds_in_code()
    assert {"error", "warning", "internal error", "interrupted"} <= kinds
    assert not kinds - set(messages.LINES), sorted(kinds - set(messages.LINES))


def test_the_finders_find_a_new_check_and_a_new_error(tmp_path):
    """The test can fail: a planted module with a new check, a new error class and a new kind of line."""
    (tmp_path / "planted.py").write_text(
        "from .errors import InputError\n\n\nclass BoardTooSmall(InputError):\n    pass\n\n\n"
        "def run(rig, checks):\n    checks['exposure'] = {'ok': True}\n    rig.checks.update({'blur': {}})\n"
        "    checks = dict(glare={})\n    print(f'[red]dualcal: fatal:[/] {rig}')\n")
    (tmp_path / "errors.py").write_text("class DualcalError(Exception):\n    pass\n\n\n"
                                        "class InputError(DualcalError):\n    pass\n")
    assert check_names_in_code(tmp_path) == {"exposure", "blur", "glare"}
    assert error_classes_in_code(tmp_path) == {"DualcalError", "InputError", "BoardTooSmall"}
    assert line_kinds_in_code(tmp_path) == {"fatal"}


def test_every_entry_says_what_it_means_why_and_what_to_do():
    for table in (messages.CHECKS, messages.ERRORS, messages.LINES):
        for name, entry in table.items():
            assert {"title", "meaning", "cause", "action"} <= set(entry), name
            assert all(len(entry[k]) > 10 for k in ("meaning", "cause", "action")), name


def test_the_messages_an_entry_quotes_are_in_the_code():
    """An entry's examples are fragments of messages the code prints: a reworded message fails here."""
    strings = list(_strings())
    missing = [(name, e) for table in (messages.CHECKS, messages.ERRORS, messages.LINES)
               for name, entry in table.items() for e in entry.get("examples", ())
               if not any(e in s for s in strings)]
    assert not missing


def test_an_entry_is_named_by_its_page_and_anchor():
    assert messages.page_of("rig_rigid") == "docs/checks.md#rig_rigid"
    assert messages.page_of("InputError") == "docs/checks.md#inputerror"
    assert messages.page_of("internal error") == "docs/checks.md#internal-error"
    with pytest.raises(KeyError):
        messages.page_of("no_such_check")


def test_every_command_help_ends_with_a_page_that_exists(run_cli):
    from dualcal.cli import cli

    for name in cli.commands:
        page = messages.command_page(name)
        assert (DOCS / page.split("/", 1)[1].split("#")[0]).is_file(), page
        res = run_cli(name, "--help")
        assert res.code == 0 and res.out.rstrip().endswith(f"Documentation: {page}"), name
    res = run_cli("--help")
    assert res.out.rstrip().splitlines()[-1].strip().startswith(f"Documentation: {messages.DOCS}/index.md")


def test_an_error_line_names_its_entry(run_cli, tmp_path):
    res = run_cli("evaluate", tmp_path / "missing.json", "-o", tmp_path / "eval.json")
    assert res.code == 2 and len(res.err_lines) == 1
    assert res.err_lines[0].startswith("dualcal: error: ") and res.err_lines[0].endswith(
        "(see docs/checks.md#inputerror)")
