"""The generated parts of the documentation, made on every build (mkdocs-gen-files runs this script).

* *Checks and messages* (``checks.md``): its entries, from the one table in the code, :mod:`dualcal.messages`.
* *File formats* (``reference/formats/NAME.md``): the keys of every JSON Schema of ``src/dualcal/files/schemas``,
  appended to the page written by hand where there is one.
* *Command line* (``reference/cli.md``): every command's ``--help``, as click formats it, appended to the page.
* *Python API* (``reference/api.md``): every name of ``dualcal.__all__`` and the modules the how-to pages use,
  rendered by mkdocstrings from the docstrings. A public name without a numpydoc docstring (a summary, and
  ``Parameters`` / ``Returns`` where it has them) is a warning, and so fails the strict build.
* The figures (``figures/``, ``examples/``): :mod:`docs_figures`.
"""

from __future__ import annotations

import importlib
import inspect
import json
import logging
import sys
from pathlib import Path

import mkdocs_gen_files

DOCS = Path(__file__).resolve().parent
ROOT = DOCS.parent
sys.path[:0] = [str(ROOT / "src"), str(DOCS)]

import dualcal  # noqa: E402
from dualcal import messages  # noqa: E402

LOG = logging.getLogger("mkdocs.plugins.dualcal")      # a warning here fails the strict build


def _open(path: str, mode: str = "w"):
    return mkdocs_gen_files.open(path, mode, **({} if "b" in mode else {"encoding": "utf-8"}))


# ------------------------------------------------------------------ checks and messages

def _entry(name: str, entry: dict, titled: bool = True) -> str:
    heading = f"`{name}`: {entry['title']}" if titled else f"`{entry['title']}`"
    lines = [f"### {heading} {{#{messages._anchor(name)}}}", "",
             f"**What it means.** {entry['meaning']}", "",
             f"**Likely cause.** {entry['cause']}", "",
             f"**What to do.** {entry['action']}", ""]
    if entry.get("examples"):
        lines += ["Its messages contain: " + ", ".join(f"\"{e.strip()}\"" for e in entry["examples"]) + ".", ""]
    return "\n".join(lines)


def checks_page() -> None:
    parts = ["", "## The checks of a calibration {#checks}", "",
             "`dualcal calibrate` prints the checks that fail at its end, the report shows all of them at its top, "
             "and calib.json keeps them under `checks` (each with `ok`, `message` and its own figures).", ""]
    parts += [_entry(name, entry) for name, entry in messages.CHECKS.items()]
    parts += ["## Errors {#errors}", "",
              "An error stops the command: one line on stderr, `dualcal: error: ...`, naming what is wrong and "
              "ending with the entry below that explains its kind; exit code 2; nothing is written, and an earlier "
              "output stays as it was.", ""]
    parts += [_entry(name, entry) for name, entry in messages.ERRORS.items()]
    parts += ["## Other lines the command prints {#lines}", ""]
    parts += [_entry(name, entry, titled=False) for name, entry in messages.LINES.items()]
    with _open("checks.md", "a") as f:
        f.write("\n".join(parts))


# ------------------------------------------------------------------ file formats

SCHEMAS = ROOT / "src" / "dualcal" / "files" / "schemas"


def _type_of(node: dict) -> str:
    if "$ref" in node:
        ref = node["$ref"]
        if ref.startswith("dualcal:"):
            name, _, pointer = ref[len("dualcal:"):].partition("#")
            target = f"[{name}]({Path(name).stem}.md)"
            return f"as in {target}" + (f" (`{pointer.rsplit('/', 1)[-1]}`)" if pointer else "")
        return f"`{ref.rsplit('/', 1)[-1]}` (below)"
    kinds = node.get("type")
    kinds = " or ".join(kinds) if isinstance(kinds, list) else (kinds or "")
    if "enum" in node:
        kinds += " (" + ", ".join(f"`{json.dumps(v)}`" for v in node["enum"]) + ")"
    for key, word in (("minimum", ">="), ("exclusiveMinimum", ">"), ("maximum", "<=")):
        if key in node:
            kinds += f" {word} {node[key]}"
    if "minItems" in node and node.get("minItems") == node.get("maxItems"):
        kinds += f", {node['minItems']} items"
    for key in ("anyOf", "oneOf"):
        if key in node:
            kinds += " " + " or ".join(_type_of(n) for n in node[key])
    return kinds.strip()


def _rows(node: dict, path: str, required: bool, depth: int = 0):
    """``(key path, type, required, description)`` of ``node`` and what it contains."""
    yield path, _type_of(node), required, node.get("description", "")
    if depth > 4 or "$ref" in node:
        return
    needed = set(node.get("required", ()))
    for key, child in node.get("properties", {}).items():
        yield from _rows(child, f"{path}.{key}" if path else key, key in needed, depth + 1)
    extra = node.get("additionalProperties")
    if isinstance(extra, dict):
        yield from _rows(extra, f"{path}.<name>" if path else "<name>", False, depth + 1)
    items = node.get("items")
    if isinstance(items, dict) and (items.get("properties") or items.get("additionalProperties")):
        yield from _rows(items, f"{path}[]", False, depth + 1)


def _key_table(schema: dict) -> list[str]:
    lines = ["| key | type | required | |", "| --- | --- | --- | --- |"]
    for path, kind, required, description in _rows(schema, "", True):
        if path:
            lines.append(f"| `{path}` | {kind} | {'yes' if required else ''} | {description} |".replace("\n", " "))
    return lines


def format_pages() -> None:
    for schema_file in sorted(SCHEMAS.glob("*.json")):
        name, schema = schema_file.stem, json.loads(schema_file.read_text(encoding="utf-8"))
        page = f"reference/formats/{name}.md"
        lines = []
        if not (DOCS / page).is_file():
            lines += [f"# {name}.json", ""]
        lines += ["", "## Keys, from the JSON Schema", "",
                  f"{schema.get('description', '')} Generated from `src/dualcal/files/schemas/{name}.json`; "
                  f"`dualcal schema {name}` prints it. Every file dualcal reads is checked against it, and unknown "
                  "keys are admitted: a file written by a newer dualcal still reads.", ""]
        lines += _key_table(schema)
        for def_name, definition in schema.get("$defs", {}).items():
            if len(list(_rows(definition, "", True))) > 1:          # an object with keys, not a number's rule
                lines += ["", f"### `{def_name}`", ""] + _key_table(definition)
        lines += ["", f'??? note "The JSON Schema of {name}.json"', "", "    ```json"]
        lines += ["    " + line for line in json.dumps(schema, indent=1).splitlines()] + ["    ```", ""]
        with _open(page, "a") as f:
            f.write("\n".join(lines))


# ------------------------------------------------------------------ the command line

def cli_page() -> None:
    """Every command's ``--help`` (80 columns, as a terminal shows it), under a heading ``dualcal NAME``."""
    import click

    from dualcal.cli import cli

    def help_text(command, name, parent=None):
        ctx = click.Context(command, info_name=name, parent=parent, terminal_width=80, max_content_width=80)
        return command.get_help(ctx), ctx

    top, root = help_text(cli, "dualcal")
    parts = ["", "## dualcal", "", "```text", top, "```", ""]
    for name in sorted(cli.commands):
        text, _ = help_text(cli.commands[name], name, root)
        parts += [f"## dualcal {name}", "", "```text", text, "```", ""]
    with _open("reference/cli.md", "a") as f:
        f.write("\n".join(parts))


# ------------------------------------------------------------------ the Python API

#: The sections of the API page, by the part of ``dualcal`` a name comes from (``dualcal._API``).
API_SECTIONS = [
    ("The workflow every command runs", ("workflow",)),
    ("Cameras, boards and poses", ("geometry",)),
    ("Calibration, measurement and the checks", ("estimation",)),
    ("Photos and files", ("files",)),
    ("Synthetic rigs with known truth", ("synthetic",)),
    ("Pages", ("pages",)),
    ("Errors", ("errors",)),
]
#: Modules the how-to pages use beyond ``dualcal.__all__``, and the names of each they use (None: its ``__all__``).
API_MODULES = {
    "dualcal.estimation.advise": ["advise", "prior_from_rig", "nominal_prior", "describe", "Advice", "AdvisedPose"],
    "dualcal.files.boardprint": ["write_board"],
    "dualcal.synthetic.synth_roll": ["write_camera_roll"],
    "dualcal.files.imports": ["Imported", "write_imported"],
    "dualcal.estimation.matching": ["match_point", "Match", "epipolar_curve"],
    "dualcal.files.photos": ["read_focus", "FocusFacts"],
    "dualcal.messages": None,
}


def _docstring_problems(name: str, obj) -> list[str]:
    """What a public name's docstring lacks: a summary, and numpydoc's ``Parameters`` and ``Returns`` where the
    function has parameters and returns something (a class: its ``__init__``'s parameters, or its fields)."""
    if not (inspect.isclass(obj) or inspect.isroutine(obj)):
        return []                      # data: its docstring follows its assignment, where griffe reads it
    doc = obj.__doc__
    if inspect.isclass(obj) and doc and doc.startswith(f"{obj.__name__}("):      # a dataclass's generated one
        doc = None
    if not doc or not doc.strip():
        return [f"{name} has no docstring"]
    if inspect.isclass(obj):               # its public methods and properties, which the page shows too
        return [f"{name}.{member} has no docstring" for member, value in vars(obj).items()
                if not member.startswith("_") and (callable(value) or isinstance(value, property))
                and not ((value.fget if isinstance(value, property) else getattr(value, "__func__", value))
                         .__doc__ or "").strip()]
    doc = inspect.cleandoc(doc)
    signature = inspect.signature(obj)
    params = [p for p in signature.parameters if p not in ("self", "cls")]
    problems = []
    if params and "Parameters\n----------" not in doc:
        problems.append(f"{name}: its docstring has no numpydoc 'Parameters' section")
    returns = signature.return_annotation
    if returns not in (None, "None", inspect.Signature.empty) and not any(
            f"{s}\n{'-' * len(s)}" in doc for s in ("Returns", "Yields")):
        problems.append(f"{name}: its docstring has no numpydoc 'Returns' section")
    return problems


def api_page() -> None:
    names = sorted(n for n in dualcal._API)
    parts = ["# Python API", "",
             "The package is the API: every command is a thin shell over these functions (see "
             "[Architecture](../architecture.md)). `import dualcal` is light: each name is imported on first use. "
             "Conventions (pixels, the board, poses, omega-phi-kappa, sigma) are written once in "
             "[Conventions](conventions.md). This page is generated from the docstrings.", ""]
    done = set()
    for title, prefixes in API_SECTIONS:
        chosen = [n for n in names if dualcal._API[n].split(".")[0] in prefixes]
        if not chosen:
            continue
        parts += [f"## {title}", ""]
        for name in chosen:
            obj = getattr(dualcal, name)                  # where it is defined (a package may re-export it)
            parts += [f"::: {obj.__module__}.{obj.__qualname__}", "    options:",
                      f"      heading: dualcal.{name}", f"      toc_label: {name}", ""]
            done.add(name)
    for name in names:
        if name not in done:
            LOG.warning("dualcal.%s (from %s) belongs to no section of the API page: add its part to API_SECTIONS "
                        "in docs/gen_pages.py", name, dualcal._API[name])
    parts += ["## Modules the how-to pages use", ""]
    for module, members in API_MODULES.items():
        members = members or importlib.import_module(module).__all__
        parts += [f"::: {module}", "    options:", "      show_root_full_path: true", "      heading_level: 3",
                  f"      members: [{', '.join(members)}]", ""]
    with _open("reference/api.md") as f:
        f.write("\n".join(parts))
    problems = []
    for name in names:
        problems += _docstring_problems(f"dualcal.{name}", getattr(dualcal, name))
    for module, members in API_MODULES.items():
        mod = importlib.import_module(module)
        problems += [f"{module}: no module docstring"] * (not mod.__doc__)
        for member in members or mod.__all__:
            problems += _docstring_problems(f"{module}.{member}", getattr(mod, member))
    for problem in problems:
        LOG.warning("API reference: %s", problem)


# ------------------------------------------------------------------ figures

def figures() -> None:
    import docs_figures

    for path, data in docs_figures.all_figures().items():
        with _open(path, "wb") as f:
            f.write(data)


def main() -> None:
    checks_page()
    format_pages()
    cli_page()
    api_page()
    figures()


if __name__ == "<run_path>":            # run by mkdocs-gen-files (runpy.run_path); a test may import it
    main()
