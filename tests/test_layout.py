"""The package layout: one sub-package per layer, and imports only downwards (README, "Architecture").

Read from the syntax tree of every module of ``src/dualcal`` (lazy imports inside functions too): no library
module imports from ``dualcal.cli``; a module of a layer imports only from its own layer, the layers before it
(``dualcal._LAYERS``, in order) and the cross-cutting modules at the top (``dualcal._CROSS_CUTTING``), which import
only each other.
"""

from __future__ import annotations

import ast
from pathlib import Path

import dualcal

PACKAGE_DIR = Path(dualcal.__file__).parent
LAYERS, CROSS_CUTTING = dualcal._LAYERS, dualcal._CROSS_CUTTING


def module_name(path: Path, package_dir: Path) -> tuple[str, bool]:
    """``dualcal.geometry.camera`` for ``.../dualcal/geometry/camera.py``, and whether it is a package."""
    parts = list(path.relative_to(package_dir.parent).with_suffix("").parts)
    if parts[-1] == "__init__":
        return ".".join(parts[:-1]), True
    return ".".join(parts), False


def imported_modules(source: str, module: str, is_package: bool, package_dir: Path) -> set[str]:
    """Every ``dualcal`` module one module's source imports, absolute names; a name taken from the package
    itself counts as the module the API table (``dualcal._API``) takes it from."""
    package = module if is_package else module.rpartition(".")[0]
    found = set()
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            found |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                parts = package.split(".")
                base = ".".join(parts[:len(parts) - node.level + 1] + ([node.module] if node.module else []))
            else:
                base = node.module or ""
            for alias in node.names:
                full = f"{base}.{alias.name}"
                path = package_dir.parent.joinpath(*full.split("."))
                if path.with_suffix(".py").is_file() or (path / "__init__.py").is_file():
                    found.add(full)
                elif base == "dualcal" and alias.name in dualcal._API:
                    found.add(f"dualcal.{dualcal._API[alias.name]}")
                else:
                    found.add(base)
    return {m for m in found if m == "dualcal" or m.startswith("dualcal.")}


def place(module: str) -> str:
    """``cli``, ``app``, a layer's name, ``cross-cutting``, ``package`` (dualcal itself) or ``above`` (the workflow)."""
    parts = module.split(".")
    if len(parts) == 1:
        return "package"
    if parts[1] in LAYERS or parts[1] in ("cli", "app"):
        return parts[1]
    return "cross-cutting" if parts[1] in CROSS_CUTTING else "above"


def violations(package_dir: Path) -> list[str]:
    """Each import against the layer rule, as ``importer -> imported (why)``."""
    found = []
    for path in sorted(package_dir.rglob("*.py")):
        module, is_package = module_name(path, package_dir)
        here = place(module)
        for target in sorted(imported_modules(path.read_text(encoding="utf-8"), module, is_package, package_dir)):
            there = place(target)
            if here in ("cli", "package") or module == "dualcal.__main__" or there == "package":
                continue                     # the commands and the package's API table stand above everything
            if there == "cli":
                found.append(f"{module} -> {target} (a library module imports the commands)")
            elif there == "app" and here != "app":
                found.append(f"{module} -> {target} (a library module imports the web app)")
            elif here == "cross-cutting" and there != "cross-cutting":
                found.append(f"{module} -> {target} (a cross-cutting module imports from {there})")
            elif here in LAYERS and there == "above":
                found.append(f"{module} -> {target} ({here} imports from the workflow above the layers)")
            elif here in LAYERS and there in LAYERS and LAYERS.index(there) > LAYERS.index(here):
                found.append(f"{module} -> {target} ({here} imports from {there}, a layer after it)")
    return found


def test_every_import_goes_down_the_layers():
    assert violations(PACKAGE_DIR) == []


def import_circles(package_dir: Path) -> list[list[str]]:
    """The circles of imports among the library's modules (lazy imports inside functions too), each as its sorted
    modules: the strongly connected components of more than one module (Tarjan's). The commands (``cli``), which
    register themselves on their package, and the package's API table are left out."""
    graph = {}
    for path in sorted(package_dir.rglob("*.py")):
        module, is_package = module_name(path, package_dir)
        if place(module) not in ("cli", "package"):
            graph[module] = {t for t in imported_modules(path.read_text(encoding="utf-8"), module, is_package,
                                                         package_dir) if t != module}
    index, low, stack, on_stack, circles = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph[v] & graph.keys()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while not component or component[-1] != v:
                component.append(stack.pop())
                on_stack.discard(component[-1])
            if len(component) > 1:
                circles.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return circles


def test_no_module_imports_one_that_imports_it_back():
    """Issue 41: no import circle, lazy imports included (a function-level import that dodges a circle is one)."""
    assert import_circles(PACKAGE_DIR) == []


def test_the_circle_check_finds_a_lazy_circle(tmp_path):
    """The check can fail: two modules of one layer, one importing the other inside a function."""
    layer = LAYERS[0]
    files = {"__init__.py": "", f"{layer}/__init__.py": "", f"{layer}/a.py": "from .b import f\n",
             f"{layer}/b.py": "def f():\n    from .a import g\n", f"{layer}/c.py": "from .a import f\n"}
    for name, text in files.items():
        (tmp_path / "dualcal" / name).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / "dualcal" / name).write_text(text)
    assert import_circles(tmp_path / "dualcal") == [[f"dualcal.{layer}.a", f"dualcal.{layer}.b"]]


def test_every_sub_package_of_dualcal_is_a_layer_or_above_them():
    """The layers, and above them the commands (``cli``) and the web app (``app``, which no layer imports)."""
    sub_packages = {p.name for p in PACKAGE_DIR.iterdir() if (p / "__init__.py").is_file()}
    assert sub_packages == set(LAYERS) | {"cli", "app"}
    assert {p.stem for p in PACKAGE_DIR.glob("*.py")} >= set(CROSS_CUTTING)


def test_the_layers_import_nothing():
    """Importing a module of a layer costs only that module: the layers' ``__init__`` import nothing."""
    for layer in LAYERS:
        tree = ast.parse((PACKAGE_DIR / layer / "__init__.py").read_text(encoding="utf-8"))
        assert ast.get_docstring(tree), layer
        assert not [n for n in ast.walk(tree) if isinstance(n, (ast.Import, ast.ImportFrom))], layer


def test_the_check_finds_an_import_that_goes_up(tmp_path):
    """The check can fail: a planted tree with an upward, a lazy, a cross-cutting and a CLI import."""
    low, high = LAYERS[0], LAYERS[-1]
    files = {
        "__init__.py": "", "cli/__init__.py": "", f"{low}/__init__.py": "", f"{high}/__init__.py": "",
        "errors.py": f"from .{low} import camera\n",
        "workflow.py": f"from .{high} import tables\nfrom .app import server\n",   # the first allowed: above the layers
        "app/__init__.py": "", "app/server.py": f"from ..{low} import camera\nfrom ..workflow import x\n",  # allowed
        f"{low}/camera.py": f"from ..errors import InputError\n\n\ndef f():\n    from ..{high}.tables import t\n",
        f"{high}/tables.py": f"from ..{low} import camera\nimport dualcal.cli\nfrom dualcal import workflow\n",
    }
    for name, text in files.items():
        (tmp_path / "dualcal" / name).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / "dualcal" / name).write_text(text)
    assert violations(tmp_path / "dualcal") == [
        f"dualcal.errors -> dualcal.{low}.camera (a cross-cutting module imports from {low})",
        f"dualcal.{low}.camera -> dualcal.{high}.tables ({low} imports from {high}, a layer after it)",
        f"dualcal.{high}.tables -> dualcal.cli (a library module imports the commands)",
        f"dualcal.{high}.tables -> dualcal.workflow ({high} imports from the workflow above the layers)",
        "dualcal.workflow -> dualcal.app.server (a library module imports the web app)",
    ]
