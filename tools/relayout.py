"""Move dualcal's modules into one sub-package per layer and rewrite every reference to them (issue 23).

Usage::

    python tools/relayout.py ROOT        # ROOT: a clean git checkout of dualcal; the move is left staged

The layers, in order, are :data:`LAYERS`; each module of a layer imports only from its own layer, the
layers before it and the cross-cutting modules that stay at the top (:data:`CROSS_CUTTING`, beside
:data:`ABOVE`: the workflow, the commands and the package itself). ``tests/test_layout.py`` checks that
rule on the moved tree, from ``dualcal._LAYERS`` and ``dualcal._CROSS_CUTTING``, which this script writes.

What it does, in order:

1. refuses a tree that is already moved, that has uncommitted changes, or that holds a module or package
   of ``src/dualcal`` this mapping does not name (it lists them: add them to :data:`LAYERS`);
2. rewrites, in every file git tracks (this script excepted), every reference to a moved module:

   * imports, by their syntax tree (``.py``): relative ones in ``src`` (``from .camera import``,
     ``from .. import io``, lazy ones inside functions, each recomputed from the module's new place) and
     ``from dualcal import camera, io`` (split by layer when the names go to different ones); in other
     files (the README's examples) the one-line form of the latter;
   * dotted names anywhere, code and strings and prose: ``dualcal.camera`` -> ``dualcal.geometry.camera``
     (``import dualcal.adjust``, ``"dualcal.adjust:RIG_MODES"``, monkeypatch targets,
     ``PackageLoader("dualcal.report", ...)``, ``:mod:`` references);
   * paths: ``dualcal/schemas/`` -> ``dualcal/files/schemas/``; in Markdown a backticked module path
     (```camera.py``` -> ```geometry/camera.py```, ```detect/``` -> ```files/detect/```); in TOML the
     package-data globs (``"report/templates/*.html"`` -> ``"pages/report/templates/*.html"``);
   * the ``_API`` table of ``dualcal/__init__.py`` (public name -> module: ``"camera"`` ->
     ``"geometry.camera"``; the public API stays the same), beside which it writes the layer order;

3. ``git mv``-s every module into its layer, writes each layer's ``__init__.py`` (a docstring: what the
   layer is; no imports, so ``import dualcal`` stays light) and stages everything it changed;
4. checks the result: every relative import of ``src/dualcal`` resolves to a file, and no moved module
   reads files next to it through ``__file__`` (none does; a new one would need a look).
"""

from __future__ import annotations

import ast
import re
import subprocess
import sys
from pathlib import Path

#: The layers in order, each ``name: (docstring of its package, its modules)``.
LAYERS = {
    "geometry": (
        "The geometry: the camera and lens models, the boards, rotations and poses, the data that flows between the\n"
        "stages, and the closed forms on them (homographies and Zhang's initial calibration, space resection).\n"
        "It imports nothing of the other layers.",
        ("board", "camera", "rotation", "model", "poses", "scale", "zhang", "resection")),
    "files": (
        "Files and photos: every JSON in and out and its schema, the photos read (EXIF, RAW), datasets and camera\n"
        "rolls, their duplicates, the corners detected on them, and the undistorted and rectified photos written.\n"
        "It speaks in the geometry's types and knows nothing of the estimation.",
        ("io", "schemas", "photos", "roll", "dataset", "duplicates", "detect", "rectify", "stereo")),
    "synthetic": (
        "Synthetic truth: rigs, rolls and fleets with known parameters and photo-like renders of them, the test\n"
        "bed of the estimation (and the frame test of :mod:`dualcal.estimation.advise`).",
        ("synth", "render", "render_charuco", "render_marks", "synth_fleet", "synth_roll")),
    "estimation": (
        "The estimation: the joint adjustment and its solver, the covariance and its honest sigmas, outliers and\n"
        "model choice, the checks of a calibration, and what a calibration measures (intersection, evaluation,\n"
        "measurement, advice on the next photo).",
        ("normal_equations", "lm", "uncertainty", "distributions", "covariance", "adjust", "rig_relations",
         "loop_closure", "checks", "calibrate", "model_selection", "validation", "intersect", "evaluation",
         "measurement", "advise")),
    "pages": (
        "Pages and text: the HTML report (and the fleet, pick and advice pages), the paper's tables for the\n"
        "terminal, the exports to other tools' formats, the printable board and the choice of a board to print.",
        ("report", "tables", "export", "boardprint", "board_choice")),
}
#: Stay at the top, beside the layers: used by every layer, they import only each other.
CROSS_CUTTING = ("errors", "extras", "parallel", "progress", "terminal")
#: Stay at the top, above the layers: the package (the API), the workflow every command runs, the commands.
ABOVE = ("__init__", "__main__", "cli", "workflow", "batch")

PACKAGE = "dualcal"
TEXT_SUFFIXES = {".py", ".md", ".rst", ".txt", ".toml", ".cfg", ".ini", ".json", ".yml", ".yaml", ".html", ""}


class RelayoutError(Exception):
    pass


def layer_of() -> dict[str, str]:
    """module (or package) name -> its layer."""
    return {m: layer for layer, (_, modules) in LAYERS.items() for m in modules}


def top_level_entries(pkg_dir: Path) -> set[str]:
    """The modules and folders directly in ``src/dualcal`` (``camera`` for camera.py, ``detect`` for detect/)."""
    names = {p.stem for p in pkg_dir.glob("*.py")}
    names |= {p.name for p in pkg_dir.iterdir() if p.is_dir() and p.name != "__pycache__" and not p.name.startswith(".")}
    return names


def check_tree(root: Path) -> set[str]:
    """The moved names present; :class:`RelayoutError` when the tree is moved already, dirty or not mapped."""
    pkg_dir = root / "src" / PACKAGE
    if not pkg_dir.is_dir():
        raise RelayoutError(f"{pkg_dir} is not a directory: ROOT must be a dualcal checkout")
    moved = [layer for layer in LAYERS if (pkg_dir / layer).exists()]
    if moved:
        raise RelayoutError(f"already moved: {', '.join(moved)} exist in {pkg_dir}")
    status = git(root, "status", "--porcelain").strip()
    if status:
        raise RelayoutError("the checkout has uncommitted changes or untracked files:\n" + status)
    mapping = layer_of()
    entries = top_level_entries(pkg_dir)
    unmapped = sorted(entries - set(mapping) - set(CROSS_CUTTING) - set(ABOVE))
    if unmapped:
        raise RelayoutError("modules of src/dualcal that tools/relayout.py does not place (add them to LAYERS, "
                            "CROSS_CUTTING or ABOVE):\n  " + "\n  ".join(unmapped))
    missing = sorted(set(mapping) - entries)
    if missing:
        print("note: mapped but not in the tree (left out): " + ", ".join(missing))
    return entries & set(mapping)


def git(root: Path, *args: str) -> str:
    done = subprocess.run(["git", "-C", str(root), *args], capture_output=True, text=True)
    if done.returncode:
        raise RelayoutError(f"git {' '.join(args)}: {done.stderr.strip()}")
    return done.stdout


# ---------------------------------------------------------------- names

class Names:
    """The old and new dotted names of the moved modules."""

    def __init__(self, pkg_dir: Path, present: set[str]):
        self.pkg_dir = pkg_dir
        layers = layer_of()
        self.layer = {m: layers[m] for m in present}
        alternatives = "|".join(sorted(self.layer, key=len, reverse=True))
        self.dotted = re.compile(rf"(?<![\w.]){PACKAGE}\.({alternatives})\b")
        self.slashed = re.compile(rf"(?<![\w.]){PACKAGE}/({alternatives})\b")
        self.backticked = re.compile(rf"(?<=`)({alternatives})(?=\.py\b|/)")
        self.quoted_path = re.compile(rf"(?<=[\"'])({alternatives})(?=/)")

    def new(self, dotted: str) -> str:
        """``dualcal.camera.x`` -> ``dualcal.geometry.camera.x``; other names unchanged."""
        parts = dotted.split(".")
        if len(parts) > 1 and parts[0] == PACKAGE and parts[1] in self.layer:
            return ".".join([PACKAGE, self.layer[parts[1]], *parts[1:]])
        return dotted

    def is_module(self, dotted: str) -> bool:
        """Whether ``dualcal.x.y`` names a module or package of the old tree."""
        parts = dotted.split(".")
        if parts[0] != PACKAGE:
            return False
        path = self.pkg_dir.joinpath(*parts[1:])
        return path.with_suffix(".py").is_file() or (path / "__init__.py").is_file()

    def module_of(self, rel: Path) -> tuple[str, str, bool]:
        """A file under src/: its old module name, its new one, whether it is a package's ``__init__``."""
        parts = list(rel.with_suffix("").parts)
        is_pkg = parts[-1] == "__init__"
        if is_pkg:
            parts = parts[:-1]
        old = ".".join(parts)
        return old, self.new(old), is_pkg

    def new_path(self, rel: Path) -> Path:
        """A path relative to ROOT after the move (``src/dualcal/camera.py`` -> ``src/dualcal/geometry/camera.py``)."""
        parts = rel.parts
        if len(parts) > 2 and parts[:2] == ("src", PACKAGE):
            module = parts[2][:-3] if parts[2].endswith(".py") else parts[2]
            if module in self.layer:
                return Path("src", PACKAGE, self.layer[module], *parts[2:])
        return rel


# ---------------------------------------------------------------- imports

def resolve_relative(package: str, level: int, module: str | None) -> str:
    """The absolute base of ``from <level dots><module> import`` in ``package``."""
    parts = package.split(".")
    if level - 1 > len(parts) - 1:
        raise RelayoutError(f"relative import beyond the top in {package}")
    base = parts[:len(parts) - (level - 1)]
    return ".".join(base + ([module] if module else []))


def relative_spec(package: str, target: str) -> str:
    """``from <spec> import`` for ``target`` seen from ``package`` (both absolute, inside dualcal)."""
    p, t = package.split("."), target.split(".")
    common = 0
    while common < min(len(p), len(t)) and p[common] == t[common]:
        common += 1
    return "." * (len(p) - common + 1) + ".".join(t[common:])


def import_groups(names: Names, base: str, aliases: list[tuple[str, str | None]]) -> list[tuple[str, list]]:
    """The aliases of ``from base import ...`` grouped by their new base, in their order."""
    groups: dict[str, list] = {}
    for name, asname in aliases:
        full = f"{base}.{name}"
        if name != "*" and names.is_module(full):
            new_base = names.new(full).rsplit(".", 1)[0]
        else:
            new_base = names.new(base)
        groups.setdefault(new_base, []).append((name, asname))
    return list(groups.items())


def alias_text(aliases) -> str:
    return ", ".join(n if a is None else f"{n} as {a}" for n, a in aliases)


#: Lines as long as the code's: an import that grows past it is wrapped in parentheses.
WIDTH = 120


def format_from(col: int, spec: str, aliases, first: bool = True) -> str:
    """``from spec import ...`` starting at column ``col`` (indented unless ``first``), wrapped at :data:`WIDTH`."""
    indent = " " * col
    text = f"from {spec} import {alias_text(aliases)}"
    if col + len(text) > WIDTH:
        head = f"from {spec} import ("
        words = [alias_text([a]) + ("," if i < len(aliases) - 1 else ")") for i, a in enumerate(aliases)]
        rows = [head + words[0]]
        for word in words[1:]:
            if col + len(rows[-1]) + 1 + len(word) > WIDTH:
                rows.append(indent + " " * len(head) + word)
            else:
                rows[-1] += " " + word
        text = "\n".join(rows)
    return text if first else indent + text


FROM_SPEC = re.compile(rb"from\s+(\.*\s*[\w.]*)\s+import\b")


def rewrite_python(text: str, names: Names, importer: tuple[str, str, bool] | None) -> str:
    """The imports of one file rewritten; ``importer``: its (old, new, is_package) name if it is in src/dualcal."""
    tree = ast.parse(text)
    lines = text.encode("utf-8").splitlines(keepends=True)
    edits = []                                     # (line, col, end_line, end_col, bytes), 0-based lines, byte cols
    for node in ast.walk(tree):
        if not isinstance(node, ast.ImportFrom):
            continue
        if node.level:
            if importer is None:
                continue
            old, new, is_pkg = importer
            base = resolve_relative(old if is_pkg else old.rsplit(".", 1)[0], node.level, node.module)
            new_package = new if is_pkg else new.rsplit(".", 1)[0]
            spec_of = lambda b: relative_spec(new_package, b)       # noqa: E731
        elif node.module == PACKAGE or (node.module or "").startswith(PACKAGE + "."):
            base, spec_of = node.module, (lambda b: b)
        else:
            continue
        groups = import_groups(names, base, [(a.name, a.asname) for a in node.names])
        if node.level == 0 and len(groups) == 1 and groups[0][0] == base:
            continue
        line, col, end_line = node.lineno - 1, node.col_offset, node.end_lineno - 1
        m = FROM_SPEC.match(lines[line], col)
        if not m:
            raise RelayoutError(f"cannot read the import at line {node.lineno}: {lines[line]!r}")
        inner = b"".join(lines[line:end_line + 1])[col:]
        inner = inner[:len(inner) - len(lines[end_line]) + node.end_col_offset]
        if len(groups) == 1 and (b"#" in inner or (line == end_line and col + len(inner) - (m.end(1) - m.start(1))
                                                   + len(spec_of(groups[0][0])) <= WIDTH)):
            edits.append((line, m.start(1), line, m.end(1), spec_of(groups[0][0]).encode()))   # only the module
        else:
            body = "\n".join(format_from(col, spec_of(b), a, first=i == 0) for i, (b, a) in enumerate(groups))
            edits.append((line, col, end_line, node.end_col_offset, body.encode()))
    if importer is not None and importer[0] == PACKAGE:
        edits += api_table_edits(tree, names)
    for line, col, end_line, end_col, new in sorted(edits, reverse=True):
        head, tail = lines[line][:col], lines[end_line][end_col:]
        lines[line:end_line + 1] = [head + new + tail]
    text = b"".join(lines).decode("utf-8")
    if importer is not None and importer[0] == PACKAGE:
        text = wrap_api_table(text)
    return text


def api_table_edits(tree: ast.Module, names: Names) -> list:
    """The values of ``_API = {...}`` in dualcal/__init__.py: ``"camera"`` -> ``"geometry.camera"``."""
    for node in tree.body:
        if isinstance(node, ast.Assign) and [getattr(t, "id", None) for t in node.targets] == ["_API"]:
            edits = []
            for value in node.value.values:
                module = value.value
                new = names.new(f"{PACKAGE}.{module}")[len(PACKAGE) + 1:]
                if new != module:
                    edits.append((value.lineno - 1, value.col_offset, value.end_lineno - 1, value.end_col_offset,
                                  repr(new).replace("'", '"').encode()))
            return edits
    raise RelayoutError("dualcal/__init__.py has no _API table")


def wrap_api_table(text: str) -> str:
    """The lines of ``_API = {...}`` that grew past :data:`WIDTH` broken after an entry."""
    start = text.index("_API = {")
    end = text.index("\n}", start)
    rows = []
    for row in text[start:end].split("\n"):
        indent = row[:len(row) - len(row.lstrip())]
        while len(row) > WIDTH and ", " in row[len(indent):WIDTH]:
            cut = row.rindex(", ", 0, WIDTH) + 1
            rows.append(row[:cut])
            row = indent + row[cut:].lstrip()
        rows.append(row)
    return text[:start] + "\n".join(rows) + text[end:]


def layer_constants() -> str:
    return ("\n#: The layers of the library, in order: a module imports only from its own layer, those before it and\n"
            "#: the cross-cutting modules beside this file (README, \"Architecture\"; tests/test_layout.py).\n"
            f"_LAYERS = {tuple(LAYERS)!r}\n"
            f"_CROSS_CUTTING = {CROSS_CUTTING!r}\n").replace("'", '"')


def add_layer_constants(text: str) -> str:
    m = re.search(r"^__version__ = .*\n", text, re.M)
    if not m:
        raise RelayoutError("dualcal/__init__.py has no __version__ line to put the layer order after")
    return text[:m.end()] + layer_constants() + text[m.end():]


ONE_LINE_FROM = re.compile(rf"^(?P<indent>[ \t]*)from (?P<base>{PACKAGE}(?:\.[\w.]+)?) import "
                           r"(?P<names>[\w]+(?: as \w+)?(?:, *[\w]+(?: as \w+)?)*)(?P<tail>[ \t]*(?:#.*)?)$", re.M)


def rewrite_one_line_imports(text: str, names: Names) -> str:
    """``from dualcal import camera, io`` lines outside Python files (the README's examples)."""
    def one(m: re.Match) -> str:
        aliases = [tuple(a.split(" as ")) if " as " in a else (a, None)
                   for a in (s.strip() for s in m["names"].split(","))]
        groups = import_groups(names, m["base"], aliases)
        if len(groups) == 1 and groups[0][0] == m["base"]:
            return m[0]
        statements = [m["indent"] + f"from {b} import {alias_text(a)}" for b, a in groups]
        comment = m["tail"].lstrip()
        if comment:                                # the comment kept in its column where it fits
            column = len(m[0]) - len(comment)
            statements[0] = statements[0].ljust(column - 1) + " " + comment
        return "\n".join(statements)
    return ONE_LINE_FROM.sub(one, text)


def rewrite_text(text: str, names: Names, suffix: str) -> str:
    """The dotted names, paths and (by suffix) backticked module paths and package-data globs."""
    text = names.dotted.sub(lambda m: f"{PACKAGE}.{names.layer[m[1]]}.{m[1]}", text)
    text = names.slashed.sub(lambda m: f"{PACKAGE}/{names.layer[m[1]]}/{m[1]}", text)
    if suffix in (".md", ".rst"):
        text = names.backticked.sub(lambda m: f"{names.layer[m[1]]}/{m[1]}", text)
    if suffix == ".toml":
        text = names.quoted_path.sub(lambda m: f"{names.layer[m[1]]}/{m[1]}", text)
    return text


def rewrite_file(root: Path, rel: Path, names: Names) -> str | None:
    """The new text of one tracked file, None if it is not text."""
    try:
        text = (root / rel).read_text(encoding="utf-8")
    except (UnicodeDecodeError, IsADirectoryError):
        return None
    importer = None
    if rel.parts[:2] == ("src", PACKAGE) and rel.suffix == ".py":
        importer = names.module_of(Path(*rel.parts[1:]))
    if rel.suffix == ".py":
        text = rewrite_python(text, names, importer)
        if importer is not None and importer[0] == PACKAGE:
            text = add_layer_constants(text)
    else:
        text = rewrite_one_line_imports(text, names)
    return rewrite_text(text, names, rel.suffix)


# ---------------------------------------------------------------- the move

def layer_init(doc: str) -> str:
    return f'"""{doc}\n\nA layer of dualcal (README, "Architecture"): its modules import only from it, the layers before it\n' \
           f'(``dualcal._LAYERS``) and the cross-cutting modules at the top (``dualcal._CROSS_CUTTING``)."""\n'


def relayout(root: Path) -> list[str]:
    """Move the tree at ``root``; returns the lines of a summary."""
    present = check_tree(root)
    pkg_dir = root / "src" / PACKAGE
    names = Names(pkg_dir, present)
    this = Path(__file__).resolve()
    texts = {}
    for rel in map(Path, git(root, "ls-files").splitlines()):
        if (root / rel).resolve() == this or rel == Path("tools", "relayout.py") or rel.suffix not in TEXT_SUFFIXES:
            continue
        new = rewrite_file(root, rel, names)
        if new is not None and new != (root / rel).read_text(encoding="utf-8"):
            texts[rel] = new
    for layer, (doc, _) in LAYERS.items():
        (pkg_dir / layer).mkdir()
        (pkg_dir / layer / "__init__.py").write_text(layer_init(doc), encoding="utf-8")
        git(root, "add", f"src/{PACKAGE}/{layer}/__init__.py")
    for module in sorted(present):
        old = Path("src", PACKAGE, module if (pkg_dir / module).is_dir() else f"{module}.py")
        git(root, "mv", str(old), str(names.new_path(old)))
    for rel, text in texts.items():
        new_rel = names.new_path(rel)
        (root / new_rel).write_text(text, encoding="utf-8")
        git(root, "add", str(new_rel))
    problems = check_moved(pkg_dir)
    if problems:
        raise RelayoutError("the moved tree needs a look:\n  " + "\n  ".join(problems))
    return [f"{layer}/: {', '.join(m for m in mods if m in present)}" for layer, (_, mods) in LAYERS.items()] + \
           [f"rewrote {len(texts)} files; the move is staged: git commit -m 'Move modules into layer subpackages "
            f"(by tools/relayout.py)'"]


def check_moved(pkg_dir: Path) -> list[str]:
    """Relative imports that resolve to no file, and moved modules that read files through ``__file__``."""
    problems = []
    for path in sorted(pkg_dir.rglob("*.py")):
        rel = path.relative_to(pkg_dir.parent)
        parts = list(rel.with_suffix("").parts)
        package = ".".join(parts[:-1])
        tree = ast.parse(path.read_text(encoding="utf-8"))
        if parts[1] in LAYERS and "__file__" in path.read_text(encoding="utf-8"):
            problems.append(f"{rel}: uses __file__ (check that the files it reads moved with it)")
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom) and node.level:
                base = resolve_relative(package, node.level, node.module)
                target = pkg_dir.parent.joinpath(*base.split("."))
                if not (target.with_suffix(".py").is_file() or (target / "__init__.py").is_file()):
                    problems.append(f"{rel}:{node.lineno}: from {'.' * node.level}{node.module or ''} -> "
                                    f"{base}, no such module")
    return problems


def main(argv: list[str]) -> int:
    if len(argv) != 1 or argv[0] in ("-h", "--help"):
        print("usage: python tools/relayout.py ROOT   (a clean git checkout of dualcal)", file=sys.stderr)
        return 2
    try:
        for line in relayout(Path(argv[0]).resolve()):
            print(line)
    except RelayoutError as exc:
        print(f"relayout: {exc}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
