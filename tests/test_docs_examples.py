"""Every command and Python snippet of the documentation runs, and prints what the page shows.

A page's fenced blocks run in order, in one folder and one Python namespace per page:

* ```` ```console ````: each ``$ dualcal ...`` line runs the command in-process; the lines after it (up to the next
  ``$``) are what it must print, matched as doctest would with ELLIPSIS: a line ``...`` skips lines, ``...`` in
  a line skips text, a number matches to 3 units of its last digit and 1e-4 of itself, and a line starting
  ``dualcal:`` is looked for on stderr. A shown ``dualcal: error:`` line means exit code 2, else 0.
  ``mkdir``, ``ls`` and ``cp`` run in a shell; what cannot run here is in :data:`NOT_RUN`, each with why.
* ```` ```python ````: run; a ```` ```text ```` block right after it is what it must print.
* ```` ```json ````: must parse.

*Getting started* runs first, in an empty folder (its practice camera roll and ``calib.json`` are made by its
own commands); every other page runs in a copy of the folder it leaves, as the pages say. Commands of the
page's prose (inline ``dualcal ...``) are checked for their command and option names.
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import re
import shlex
import shutil
import subprocess
from dataclasses import dataclass, field
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
FIRST = "getting-started.md"
PAGES = sorted(str(p.relative_to(DOCS)) for p in DOCS.rglob("*.md"))

#: Commands the tests do not run, and why. ``dualcal`` commands listed here are parsed (their options and
#: values checked by click) but not run.
NOT_RUN = {
    "make": "the set-up commands: `make test` is this suite, `make demo` its first run",
    "source": "activates the virtual environment these tests run in",
    "git": "a clone of the repository these tests run in",
    "dualcal pick": "opens a window: it needs a display (tests/test_detect.py drives the manual mode)",
    "dualcal batch": "starts a Dask cluster of processes (tests/test_batch.py runs it)",
    "dualcal app": "serves until stopped (the app's own tests run it)",
}
#: Shell commands run as they are, in the page's folder.
SHELL = ("mkdir", "ls", "cp")
#: A benchmark takes minutes and is not part of the tests by design: its script must exist.
BENCHMARK = re.compile(r"^\.venv/bin/python (benchmarks/\w+\.py)")

NUMBER = re.compile(r"[-+]?\d+(?:\.\d+)?(?:e[-+]?\d+)?")


@dataclass
class Block:
    language: str
    text: str
    line: int
    end: int = 0                          # the line after it (after its output, for a python block)
    output: str | None = None             # a python block's ```text block


@dataclass
class Run:
    failures: list[str] = field(default_factory=list)
    commands: int = 0
    snippets: int = 0


def fenced_blocks(markdown: str) -> list[Block]:
    """The page's fenced code blocks (at any indentation), in order; a ```text block right after a
    ```python block is that block's output."""
    blocks, lines, i = [], markdown.split("\n"), 0
    while i < len(lines):
        m = re.match(r"^(\s*)```(\w*)", lines[i])
        if not m:
            i += 1
            continue
        indent, language, start = m.group(1), m.group(2), i
        body, i = [], i + 1
        while i < len(lines) and lines[i].strip() != "```":
            body.append(lines[i][len(indent):])
            i += 1
        i += 1
        block = Block(language, "\n".join(body), start + 1, i)
        previous = blocks[-1] if blocks else None
        if (language == "text" and previous and previous.language == "python" and previous.output is None
                and not "\n".join(lines[previous.end:start]).strip()):
            previous.output, previous.end = block.text, i
        else:
            blocks.append(block)
    return blocks


def _pattern(expected: str) -> tuple[re.Pattern, list[str]]:
    """A regex of one expected line (whitespace collapsed, ``...`` any text, numbers captured) and its numbers."""
    parts, numbers = [], []
    for k, chunk in enumerate(" ".join(expected.split()).split("...")):
        if k:
            parts.append(".*")
        last = 0
        for m in NUMBER.finditer(chunk):
            parts += [re.escape(chunk[last:m.start()]), f"({NUMBER.pattern})"]
            numbers.append(m.group())
            last = m.end()
        parts.append(re.escape(chunk[last:]))
    return re.compile("".join(parts)), numbers


def line_matches(expected: str, actual: str) -> bool:
    pattern, numbers = _pattern(expected)
    m = pattern.fullmatch(" ".join(actual.split()))
    if not m:
        return False
    for want, got in zip(numbers, m.groups()):
        if "." not in want and "e" not in want:
            if want != got:
                return False
            continue
        ulp = 10.0 ** -len(want.split(".")[1].split("e")[0]) if "." in want else 0.0
        if abs(float(got) - float(want)) > 3 * ulp + 1e-4 * abs(float(want)):
            return False
    return True


def output_matches(expected: list[str], stdout: str, stderr: str = "") -> str | None:
    """None where the output shows ``expected``; else what is missing. A ``dualcal:`` line (a warning, an error)
    is looked for anywhere on stderr; the others in order on stdout, or on stderr where the command prints its
    result there, or on both one after the other."""
    errors = [line for line in stderr.split("\n") if line.strip()]
    for want in expected:
        if want.startswith("dualcal:") and not any(line_matches(want, line) for line in errors):
            return f"not on stderr: {want!r}"
    shown = [want for want in expected if not want.startswith("dualcal:")]
    problems = [_in_order(shown, text) for text in (stdout, stderr, stdout + "\n" + stderr)]
    return None if None in problems else problems[0]


def _in_order(expected: list[str], text: str) -> str | None:
    actual = [line for line in text.split("\n") if line.strip()]
    at, gap = 0, True
    for want in expected:
        if want.strip() == "...":
            gap = True
            continue
        found = next((k for k in range(at, len(actual) if gap else min(at + 1, len(actual)))
                      if line_matches(want, actual[k])), None)
        if found is None:
            return f"not printed{' next' if not gap else ''}: {want!r}"
        at, gap = found + 1, False
    return None


def _console_commands(block: Block) -> list[tuple[str, list[str]]]:
    commands = []
    for line in block.text.split("\n"):
        if line.startswith("$ "):
            commands.append((line[2:], []))
        elif commands and line.strip():
            commands[-1][1].append(line)
    return commands


def _not_run(command: str) -> str | None:
    words = command.split()
    return NOT_RUN.get(" ".join(words[:2])) or NOT_RUN.get(words[0])


def _parse_only(argv: list[str]) -> None:
    """Check a command's options and values as click parses them, without running it."""
    from dualcal.cli import cli

    at = next(k for k, word in enumerate(argv) if not word.startswith("-"))
    name, rest = argv[at], argv[at + 1:]
    cli.commands[name].make_context(name, list(rest))


def _run_dualcal(argv: list[str], capsys) -> tuple[int, str, str]:
    from dualcal.cli import main

    capsys.readouterr()
    try:
        main(argv)
        code = 0
    except SystemExit as exc:
        code = exc.code if isinstance(exc.code, int) else 1
    out, err = capsys.readouterr()
    return code, out, err


def run_page(page: str, folder: Path, capsys) -> Run:
    """Run every block of ``page`` in ``folder`` (the working directory while it runs)."""
    run, namespace = Run(), {"__name__": "docs"}
    text = (DOCS / page).read_text(encoding="utf-8")
    here = os.getcwd()
    os.chdir(folder)
    try:
        for block in fenced_blocks(text):
            where = f"{page}:{block.line}"
            if block.language == "console":
                for command, expected in _console_commands(block):
                    run.commands += 1
                    problem = _run_command(command, expected, folder, capsys)
                    if problem:
                        run.failures.append(f"{where}: $ {command}: {problem}")
            elif block.language == "python":
                run.snippets += 1
                capsys.readouterr()
                try:
                    exec(compile(block.text, where, "exec"), namespace)
                except Exception as exc:        # the page's failure, reported with the others
                    run.failures.append(f"{where}: {type(exc).__name__}: {exc}")
                    continue
                out = capsys.readouterr().out
                if block.output is not None:
                    problem = output_matches(block.output.split("\n"), out)
                    if problem:
                        run.failures.append(f"{where}: {problem}; it printed:\n{out}")
            elif block.language == "json":
                try:
                    json.loads(block.text)
                except ValueError as exc:
                    run.failures.append(f"{where}: not JSON: {exc}")
            elif block.language not in ("text", ""):
                run.failures.append(f"{where}: a ```{block.language} block: the runner knows console, python, "
                                    "json and text")
    finally:
        os.chdir(here)
    return run


def _run_command(command: str, expected: list[str], folder: Path, capsys) -> str | None:
    argv = shlex.split(command)
    reason = _not_run(command)
    if argv[0] == "dualcal" and reason:
        try:
            _parse_only(argv[1:])
        except Exception as exc:     # click's usage errors
            return f"does not parse: {exc}"
        return None
    if reason:
        return None
    bench = BENCHMARK.match(command)
    if bench:
        return None if (ROOT / bench.group(1)).is_file() else f"{bench.group(1)} does not exist"
    if argv[0] in SHELL:
        res = subprocess.run(command, shell=True, cwd=folder, capture_output=True, text=True)
        return None if res.returncode == 0 else f"exit {res.returncode}: {res.stderr.strip()}"
    if argv[0] != "dualcal":
        return f"{argv[0]!r}: the runner does not run it (add it to NOT_RUN with why, or to SHELL)"
    code, out, err = _run_dualcal(argv[1:], capsys)
    want = 2 if any(line.startswith("dualcal: error:") for line in expected) else 0
    if code != want:
        return f"exit code {code}, not {want}: {err.strip()[-600:]}"
    problem = output_matches(expected, out, err)
    return f"{problem}; it printed:\n{out[-3000:]}\n{err[-1500:]}" if problem else None


# ------------------------------------------------------------------ capture and the folder of Getting started

class Capture:
    """stdout and stderr of the commands and snippets while a page runs (``readouterr`` as pytest's capsys)."""

    def __enter__(self):
        self._out, self._err = io.StringIO(), io.StringIO()
        self._stack = contextlib.ExitStack()
        self._stack.enter_context(contextlib.redirect_stdout(self._out))
        self._stack.enter_context(contextlib.redirect_stderr(self._err))
        return self

    def readouterr(self):
        out, err = self._out.getvalue(), self._err.getvalue()
        for stream in (self._out, self._err):
            stream.seek(0)
            stream.truncate()
        return Captured(out, err)

    def __exit__(self, *exc):
        self._stack.close()


@dataclass
class Captured:
    out: str
    err: str

    def __iter__(self):
        return iter((self.out, self.err))


def run_page_captured(page: str, folder: Path) -> Run:
    """:func:`run_page` with its output captured and the terminal 80 columns wide, as the pages show it."""
    width = os.environ.get("COLUMNS")
    os.environ["COLUMNS"] = "80"
    try:
        with Capture() as capture:
            return run_page(page, folder, capture)
    finally:
        if width is None:
            del os.environ["COLUMNS"]
        else:
            os.environ["COLUMNS"] = width


@pytest.fixture(scope="session")
def getting_started(shared_tmp, computed_once):
    """*Getting started* run once, in an empty folder (one worker runs it, the others wait for it and reuse it):
    the folder it leaves and what its run found."""
    folder = shared_tmp / "docs-getting-started"

    def run() -> Run:
        folder.mkdir()
        return run_page_captured(FIRST, folder)

    return folder, computed_once("docs-getting-started", run)


def _runs_something(page: str) -> bool:
    """Whether the page has a command or a snippet to run (and so needs the folder of Getting started)."""
    return any(b.language in ("console", "python") for b in fenced_blocks((DOCS / page).read_text(encoding="utf-8")))


# ------------------------------------------------------------------ the tests

def test_getting_started_runs_from_an_empty_folder(getting_started):
    folder, run = getting_started
    assert not run.failures, "\n\n".join(run.failures)
    assert run.commands >= 5 and run.snippets >= 1
    assert (folder / "calib.json").is_file() and (folder / "practice" / "roll").is_dir()


@pytest.mark.parametrize("page", [p for p in PAGES if p != FIRST])
def test_every_example_of_the_page_runs(page, getting_started, tmp_path):
    """In a copy of the folder Getting started leaves, as the pages say."""
    folder = tmp_path / "work"
    if _runs_something(page):
        shutil.copytree(getting_started[0], folder)
    else:
        folder.mkdir()
    run = run_page_captured(page, folder)
    assert not run.failures, "\n\n".join(run.failures)


def test_the_pages_name_real_commands_and_options():
    """Commands in the prose (inline ``dualcal COMMAND --option``) name a command and options it has."""
    from dualcal.cli import cli

    group_options = {o for p in cli.params for o in p.opts + p.secondary_opts} | {"--help", "-h"}
    wrong = []
    for page in PAGES:
        for m in re.finditer(r"`dualcal ([a-z]+)([^`]*)`", (DOCS / page).read_text(encoding="utf-8")):
            name, rest = m.groups()
            command = cli.commands.get(name)
            if command is None:
                wrong.append(f"{page}: dualcal {name}: no such command")
                continue
            options = {o for p in command.params for o in p.opts + p.secondary_opts} | group_options
            wrong += [f"{page}: dualcal {name} {o}: no such option" for o in re.findall(r"(?<![\w-])--[a-z][\w-]*", rest)
                      if o not in options]
    assert not wrong, wrong


def test_the_runner_can_fail():
    """The output check fails on a wrong number, a missing line, a gap where none is shown, a wrong stream."""
    out = "tele fx 1514.968 0.215\nnoise\nverdict: all 8 checks pass\n"
    assert output_matches(["tele fx 1514.969 0.215", "...", "verdict: all 8 checks pass"], out) is None
    assert output_matches(["tele fx 1514.968 0.215", "verdict: all 8 checks pass"], out)        # no "...": no gap
    assert output_matches(["tele fx 1515.97 0.215"], out)                  # 1 px off: beyond 3 units and 1e-4
    assert output_matches(["verdict: all 7 checks pass"], out)                                  # integers exact
    assert output_matches(["tele fx ... 0.215"], out) is None
    assert output_matches(["dualcal: error: bad (see docs/checks.md#inputerror)"], out, "dualcal: error: bad")
    blocks = fenced_blocks("```python\nprint(1)\n```\n\n```text\n1\n```\n```console\n$ ls\n```\n")
    assert [(b.language, b.output) for b in blocks] == [("python", "1"), ("console", None)]
