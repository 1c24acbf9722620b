"""The house rules (docs/architecture.md), checked on the source so they stay true.

* ``phyir`` never imports GL or the app, lazily or not, and works with the GL packages absent;
* each package imports only packages of its own layer or below;
* no module uses another module's private names;
* no file over 600 lines, class over 350, function over 100 (outside tests);
* no test module imports another, nor a benchmark or script (by import or by path);
* nothing edits ``sys.path`` (packages import as packages: ``python -m benchmarks.NAME``);
* the GL packages are an extra, not a base dependency.
"""

from __future__ import annotations

import ast
import os
import subprocess
import sys
from pathlib import Path

import pytest
import tomllib

REPO = Path(__file__).resolve().parents[1]
GL_MODULES = ("viewer", "moderngl", "glfw", "imgui_bundle", "OpenGL")
# layer of each unit (a top-level module or subpackage of phyir, or the app); imports go down or sideways
LAYERS = {
    "phyir.errors": 0, "phyir.scene": 0, "phyir.pano": 0, "phyir.color": 0, "phyir.filters": 0,
    "phyir.transforms": 0, "phyir.geometry": 0,
    "phyir.estimators": 0,
    "phyir.io": 1, "phyir.shading": 1, "phyir.sheets": 1,
    "phyir.lighting": 2, "phyir.nets": 2, "phyir.synth": 2, "phyir.evaluation.metrics": 2,
    "phyir.learn": 3, "phyir.geometry_networks": 3,
    "phyir.inference": 4,
    "phyir.evaluation": 5, "phyir.export": 5, "phyir.insert": 5,
    "phyir.bench": 6,
    "phyir.commands": 7, "phyir.cli": 7,
    "viewer": 8,
}
SOURCE_DIRS = ("phyir", "viewer", "benchmarks", "scripts")


def module_name(path: Path) -> str:
    parts = list(path.relative_to(REPO).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def unit(module: str) -> str:
    """The layered unit a module belongs to: the longest prefix in LAYERS (``phyir.evaluation.metrics``
    is a unit of its own, below the rest of ``phyir.evaluation``), else ``phyir.X`` or the top level."""
    parts = module.split(".")
    for n in range(len(parts), 2, -1):
        if ".".join(parts[:n]) in LAYERS:
            return ".".join(parts[:n])
    return ".".join(parts[:2]) if parts[0] == "phyir" else parts[0]


def sources(*dirs: str) -> list[Path]:
    return sorted(p for d in dirs for p in (REPO / d).rglob("*.py"))


def imported_modules(tree: ast.AST) -> list[tuple[int, str]]:
    """(line, module) of every import, lazy ones included; ``from pkg import name`` counts as
    ``pkg.name`` (the name may be a module)."""
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out += [(node.lineno, a.name) for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            out += [(node.lineno, f"{node.module}.{a.name}") for a in node.names]
    return out


def test_every_library_unit_has_a_layer():
    units = {unit(module_name(p)) for p in sources("phyir")} - {"phyir"}
    assert units <= set(LAYERS), f"add a layer for {sorted(units - set(LAYERS))}"


def test_the_library_never_imports_gl_or_the_app():
    bad = [f"{p.relative_to(REPO)}:{line}: {m}" for p in sources("phyir")
           for line, m in imported_modules(ast.parse(p.read_text())) if m.split(".")[0] in GL_MODULES]
    bad += [f"{p.relative_to(REPO)}: names a GL module in import_module()" for p in sources("phyir")
            if any(f'import_module("{g}' in p.read_text() for g in GL_MODULES)]
    assert not bad, "\n".join(bad)


def test_imports_never_go_up_a_layer():
    bad = []
    for p in sources("phyir", "viewer"):
        me = unit(module_name(p))
        if me == "phyir":  # the package's facade (lazy names)
            continue
        for line, m in imported_modules(ast.parse(p.read_text())):
            if m.split(".")[0] not in ("phyir", "viewer"):
                continue
            them = unit(m)
            if them == "phyir":
                bad.append(f"{p.relative_to(REPO)}:{line}: {m} (the facade; import from its module)")
            elif them in LAYERS and LAYERS[them] > LAYERS[me]:
                bad.append(f"{p.relative_to(REPO)}:{line}: {me} (layer {LAYERS[me]}) imports {m} "
                           f"(layer {LAYERS[them]})")
    assert not bad, "\n".join(bad)


def private_uses(tree: ast.AST) -> list[tuple[int, str]]:
    """``from m import _x`` and ``alias._x`` where ``alias`` is an imported module or name."""
    names: set[str] = set()
    out = []
    for node in ast.walk(tree):
        if isinstance(node, (ast.Import, ast.ImportFrom)):
            for a in node.names:
                names.add(a.asname or a.name.split(".")[0])
                private = a.name.startswith("_") and not a.name.startswith("__")
                if isinstance(node, ast.ImportFrom) and private:
                    out.append((node.lineno, f"from {node.module} import {a.name}"))
    for node in ast.walk(tree):
        if (isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) and node.value.id in names
                and node.attr.startswith("_") and not node.attr.startswith("__")):
            out.append((node.lineno, f"{node.value.id}.{node.attr}"))
    return out


def test_no_module_uses_another_modules_private_names():
    bad = [f"{p.relative_to(REPO)}:{line}: {use}" for p in sources(*SOURCE_DIRS)
           for line, use in private_uses(ast.parse(p.read_text()))]
    assert not bad, "\n".join(bad)


def _private(name: str) -> bool:
    return name.startswith("_") and not name.startswith("__")


def private_attributes(tree: ast.AST) -> tuple[set[str], list[tuple[int, str]]]:
    """(the private attributes a file sets, (line, name) of each private attribute it reads).
    Setting is an assignment or ``del`` of ``anything._x`` (``self._x: T`` with no value declares,
    sets nothing), ``setattr(o, "_x", v)``, or a method or value ``_x`` in a class body; reading is
    any other ``anything._x`` and ``getattr``/``hasattr(o, "_x")``."""
    declared = {id(n.target) for n in ast.walk(tree) if isinstance(n, ast.AnnAssign) and n.value is None}
    sets: set[str] = set()
    uses: list[tuple[int, str]] = []
    for node in ast.walk(tree):
        if isinstance(node, ast.ClassDef):
            for b in node.body:
                if isinstance(b, (ast.FunctionDef, ast.AsyncFunctionDef)):
                    sets.add(b.name)
                targets = b.targets if isinstance(b, ast.Assign) else (
                    [b.target] if isinstance(b, ast.AnnAssign) and b.value is not None else [])
                sets.update(t.id for t in targets if isinstance(t, ast.Name))
        elif isinstance(node, ast.Attribute) and _private(node.attr) and id(node) not in declared:
            if isinstance(node.ctx, (ast.Store, ast.Del)):
                sets.add(node.attr)
            else:
                uses.append((node.lineno, node.attr))
        elif (isinstance(node, ast.Call) and isinstance(node.func, ast.Name)
              and node.func.id in ("setattr", "getattr", "hasattr") and len(node.args) >= 2
              and isinstance(node.args[1], ast.Constant) and isinstance(node.args[1].value, str)
              and _private(node.args[1].value)):
            if node.func.id == "setattr":
                sets.add(node.args[1].value)
            else:
                uses.append((node.lineno, node.args[1].value))
    return {s for s in sets if _private(s)}, uses


def cross_file_privates(trees: dict[str, ast.AST]) -> list[str]:
    """``file:line: _x (set in ...)`` for each private attribute read in a file that doesn't set it
    but another of ``trees`` does (names set nowhere among them, a library's, are not counted)."""
    found = {name: private_attributes(tree) for name, tree in trees.items()}
    owners: dict[str, set[str]] = {}
    for name, (sets, _) in found.items():
        for attr in sets:
            owners.setdefault(attr, set()).add(name)
    return [f"{name}:{line}: {attr} (set in {', '.join(sorted(owners[attr]))})"
            for name, (sets, uses) in found.items() for line, attr in uses
            if attr not in sets and attr in owners]


@pytest.mark.parametrize("package", ["phyir", "viewer", "benchmarks"])
def test_no_private_attribute_is_used_outside_the_file_that_sets_it(package):
    """A part reads another's state through a public name (a property, a method): the file that
    sets ``_x`` is the only one that reads it."""
    trees = {p.relative_to(REPO).as_posix(): ast.parse(p.read_text()) for p in sources(package)}
    bad = cross_file_privates(trees)
    assert not bad, "\n".join(bad)


def test_the_private_attribute_rule_flags_reads_from_another_file():
    flagged = {"a.py": "class A:\n    def __init__(self):\n        self._x = 1\n    def _f(self): pass",
               "b.py": "class B:\n    _x: int\n    def g(self):\n        return self._x + self._f()\n"
                       "    def h(self, o):\n        return getattr(o, '_x')"}
    assert sorted(b.split(": ", 1)[1] for b in cross_file_privates(
        {n: ast.parse(s) for n, s in flagged.items()})) == ["_f (set in a.py)", "_x (set in a.py)",
                                                             "_x (set in a.py)"]
    allowed = {"a.py": "class A:\n    def __init__(self):\n        self._x = 1\n    def f(self):\n"
                       "        return self._x + self._g()\n    def _g(self): pass",
               "b.py": "import enum\nclass B:\n    def __init__(self):\n        self._x = 2\n"
                       "    def f(self, o):\n        return self._x + o.__class__ + enum.Key._1"}
    assert not cross_file_privates({n: ast.parse(s) for n, s in allowed.items()})


ESTIMATOR_GROUPS = ("phyir.lighting_methods", "phyir.geometry_networks")


def estimator_listings(tree: ast.AST, groups: dict[str, set[str]]) -> list[tuple[int, str]]:
    """(line, group) of each place that names a group's estimators by hand: a literal tuple, list
    or set holding all of a group's names (two or more), or an argparse ``choices=`` literal holding
    any of them."""
    found = []
    for node in ast.walk(tree):
        literal = None
        if isinstance(node, (ast.Tuple, ast.List, ast.Set)):
            literal, whole = node, True
        elif isinstance(node, ast.keyword) and node.arg == "choices" and isinstance(
                node.value, (ast.Tuple, ast.List, ast.Set)):
            literal, whole = node.value, False
        if literal is None:
            continue
        strings = {e.value for e in literal.elts if isinstance(e, ast.Constant)}
        for group, names in groups.items():
            if (whole and len(names) > 1 and names <= strings) or (not whole and names & strings):
                found.append((literal.lineno, group))
    return found


def test_the_estimator_names_are_defined_once():
    """Lighting methods and geometry networks are named by the registry (phyir.estimators, filled
    from the entry points): no tuple of their names kept in step by hand, no hand-written choices."""
    entry = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]["entry-points"]
    groups = {g: set(entry[g]) for g in ESTIMATOR_GROUPS}
    assert {"fused", "lnet", "projection"} <= groups["phyir.lighting_methods"]
    assert "gmnet" in groups["phyir.geometry_networks"]
    bad = [f"{p.relative_to(REPO)}:{line}: lists the {group} (use phyir.estimators)"
           for p in sources(*SOURCE_DIRS)
           for line, group in estimator_listings(ast.parse(p.read_text()), groups)]
    assert not bad, "\n".join(bad)


def test_the_estimator_rule_flags_hand_written_lists():
    groups = {"light": {"a", "b"}, "geo": {"g"}}
    flagged = "X = ('a', 'b', 'c')\np.add_argument('--geometry', choices=['g'])\n"
    assert estimator_listings(ast.parse(flagged), groups) == [(1, "light"), (2, "geo")]
    allowed = "X = ('a', 'c')\nY = ('g', 'lnet')\np.add_argument('--geometry', choices=names())\n"
    assert estimator_listings(ast.parse(allowed), groups) == []


def test_sizes_stay_on_a_screen():
    bad = []
    for p in sources(*SOURCE_DIRS):
        text = p.read_text()
        if text.count("\n") > 600:
            bad.append(f"{p.relative_to(REPO)}: {text.count(chr(10))} lines (at most 600)")
        for node in ast.walk(ast.parse(text)):
            n = getattr(node, "end_lineno", 0) - getattr(node, "lineno", 0) + 1
            if isinstance(node, ast.ClassDef) and n > 350:
                bad.append(f"{p.relative_to(REPO)}:{node.lineno}: class {node.name} {n} lines (at most 350)")
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)) and n > 100:
                bad.append(f"{p.relative_to(REPO)}:{node.lineno}: {node.name}() {n} lines (at most 100)")
    assert not bad, "\n".join(bad)


def modules_under_tests() -> set[str]:
    """Import names of the modules under tests/ that no module may import: every one (test_*.py,
    conftest, anything else) except the shared builders of tests/support/ (imported as ``support.*``)."""
    root = REPO / "tests"
    return {p.stem for p in root.rglob("*.py")
            if p.stem != "__init__" and p.relative_to(root).parts[0] != "support"}


def imports_of_test_modules(tree: ast.AST, forbidden: set[str]) -> list[tuple[int, str]]:
    """(line, module) of the imports in ``tree`` of a module named in ``forbidden`` (or of the tests
    folder itself); the packages ``phyir`` and ``viewer`` and ``support.*`` are fine."""
    bad = []
    for line, m in imported_modules(tree):
        parts = m.split(".")
        if parts[0] in ("phyir", "viewer", "support"):
            continue
        if parts[0] == "tests" or any(part in forbidden for part in parts[:2]):
            bad.append((line, m))
    return bad


def test_no_test_module_imports_another():
    forbidden = modules_under_tests()
    assert {"conftest", "test_layering", "test_io", "test_viewer_app"} <= forbidden
    assert not forbidden & {"scenes", "tiny_scenes", "corpus", "paths"}
    bad = [f"{p.relative_to(REPO)}:{line}: imports {m}" for p in sorted((REPO / "tests").rglob("*.py"))
           for line, m in imports_of_test_modules(ast.parse(p.read_text()), forbidden)]
    assert not bad, "\n".join(bad)


def test_the_test_import_rule_flags_test_modules_and_allows_support():
    forbidden = modules_under_tests()
    flagged = ["import test_io", "from test_viewer_app import FakeModel", "from conftest import PANOS",
               "import conftest", "from tests.test_io import x", "from tests import conftest",
               "def f():\n    from test_bad_inputs import corpus_outcomes"]
    allowed = ["from support.scenes import box_room", "from support import viewer", "import support.corpus",
               "from phyir.io import exr", "import viewer.app", "from viewer.gl import window",
               "import numpy"]
    for src in flagged:
        assert imports_of_test_modules(ast.parse(src), forbidden), src
    for src in allowed:
        assert not imports_of_test_modules(ast.parse(src), forbidden), src


# The one file that may edit sys.path: it runs inside Blender's own Python (``phyir export --blend``,
# or Blender's Text editor), where phyir's environment is not installed, and lends that Python the
# numpy of the environment that launched it (ensure_numpy) for Blender's glTF importer.
SYS_PATH_EXEMPT = {"phyir/export/blender_scene.py"}
# folders that hold no source of the repository (environments, caches, runs and data sets)
NOT_SOURCE = {"runs", "data", "out", "build", "node_modules", "__pycache__"}
SYS_PATH_METHODS = {"insert", "append", "extend", "remove", "pop", "clear", "reverse", "sort", "__setitem__",
                    "__delitem__", "__iadd__"}


def repository_python_files() -> list[Path]:
    """Every ``.py`` file of the repository: all folders but hidden ones (.venv, .git, caches) and
    :data:`NOT_SOURCE`."""
    out = []
    for root, dirs, files in os.walk(REPO):
        dirs[:] = sorted(d for d in dirs if not d.startswith(".") and d not in NOT_SOURCE
                         and not d.endswith(".egg-info"))
        out += [Path(root) / f for f in sorted(files) if f.endswith(".py")]
    return out


def sys_path_edits(tree: ast.AST) -> list[tuple[int, str]]:
    """(line, code) of every change to ``sys.path``: one of its mutating methods called, the name or an
    item or slice of it assigned (``=``, ``+=``) or deleted, ``site.addsitedir``; ``sys``, ``path``
    and ``addsitedir`` under any name they are imported as."""
    sys_names, path_names, addsitedir = set(), set(), set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for a in node.names:
                if a.name == "sys":
                    sys_names.add(a.asname or "sys")
                elif a.name == "site":
                    addsitedir.add(f"{a.asname or 'site'}.addsitedir")
        elif isinstance(node, ast.ImportFrom) and node.module in ("sys", "site") and node.level == 0:
            for a in node.names:
                if node.module == "sys" and a.name == "path":
                    path_names.add(a.asname or "path")
                elif node.module == "site" and a.name == "addsitedir":
                    addsitedir.add(a.asname or "addsitedir")

    def is_path(e: ast.AST) -> bool:
        if isinstance(e, ast.Subscript):
            return is_path(e.value)
        if isinstance(e, ast.Attribute):
            return e.attr == "path" and isinstance(e.value, ast.Name) and e.value.id in sys_names
        return isinstance(e, ast.Name) and e.id in path_names

    out = []
    for node in ast.walk(tree):
        targets = []
        if isinstance(node, ast.Call):
            f = node.func
            if isinstance(f, ast.Attribute) and f.attr in SYS_PATH_METHODS and is_path(f.value):
                out.append((node.lineno, ast.unparse(node)))
            elif ast.unparse(f) in addsitedir:
                out.append((node.lineno, ast.unparse(node)))
        elif isinstance(node, (ast.Assign, ast.Delete)):
            targets = node.targets
        elif isinstance(node, (ast.AugAssign, ast.AnnAssign)):
            targets = [node.target]
        for t in targets:
            for e in (t.elts if isinstance(t, (ast.Tuple, ast.List)) else [t]):
                if is_path(e):
                    out.append((node.lineno, ast.unparse(node)))
    return out


def test_nothing_edits_sys_path():
    """Packages import as packages (``python -m benchmarks.NAME`` from the repository root, the tests
    through pyproject's ``pythonpath``), never by adding folders to ``sys.path`` at run time."""
    files = repository_python_files()
    assert {"phyir/cli.py", "benchmarks/__init__.py", "tests/test_layering.py"} <= {
        p.relative_to(REPO).as_posix() for p in files}
    bad, exempt = [], []
    for p in files:
        rel = p.relative_to(REPO).as_posix()
        for line, code in sys_path_edits(ast.parse(p.read_text(encoding="utf-8"))):
            (exempt if rel in SYS_PATH_EXEMPT else bad).append(f"{rel}:{line}: {code}")
    assert not bad, "edits sys.path:\n" + "\n".join(bad)
    assert exempt, f"{sorted(SYS_PATH_EXEMPT)} no longer edits sys.path: drop the exemption"


def test_the_sys_path_rule_flags_every_kind_of_edit():
    flagged = ["import sys\nsys.path.insert(0, 'x')", "import sys\nsys.path.append('x')",
               "import sys as s\ns.path.extend(['x'])", "import sys\nsys.path = ['x']",
               "import sys\nsys.path[:0] = ['x']", "import sys\nsys.path += ['x']",
               "import sys\ndel sys.path[0]", "from sys import path\npath.insert(0, 'x')",
               "from sys import path as p\np.remove('x')", "import site\nsite.addsitedir('x')",
               "from site import addsitedir\naddsitedir('x')",
               "import sys\ndef f():\n    sys.path.insert(0, 'x')"]
    allowed = ["import sys\nprint(sys.path)", "import sys\nx = list(sys.path)",
               "import os\nos.path.join('a')", "from pathlib import Path\nPath('x')",
               "import sys\nif 'x' in sys.path: pass",
               "path = []\npath.append(1)", "import sys\nsys.argv.insert(0, 'x')"]
    for src in flagged:
        assert sys_path_edits(ast.parse(src)), src
    for src in allowed:
        assert not sys_path_edits(ast.parse(src)), src


def loads_by_path_or_imports_tools(tree: ast.AST) -> list[tuple[int, str]]:
    """(line, what) of a test's imports of ``benchmarks`` or ``scripts`` and of its module loads by
    file path (``spec_from_file_location``, ``SourceFileLoader``, ``runpy``)."""
    out = [(line, m) for line, m in imported_modules(tree)
           if m.split(".")[0] in ("benchmarks", "scripts", "runpy")]
    for node in ast.walk(tree):
        if isinstance(node, (ast.Attribute, ast.Name)):
            name = node.attr if isinstance(node, ast.Attribute) else node.id
            if name in ("spec_from_file_location", "SourceFileLoader", "run_path"):
                out.append((node.lineno, name))
    return out


def test_tests_use_the_library_not_benchmarks_or_scripts():
    """What a test checks lives in the library or in tests/support/, not in a benchmark or a script
    (which the tests would have to load by path)."""
    bad = [f"{p.relative_to(REPO)}:{line}: {what}" for p in sorted((REPO / "tests").rglob("*.py"))
           for line, what in loads_by_path_or_imports_tools(ast.parse(p.read_text(encoding="utf-8")))]
    assert not bad, "\n".join(bad)
    for src in ("from benchmarks.insert_gallery import vase", "import scripts.points_table",
                "import importlib.util\nimportlib.util.spec_from_file_location('m', 'x.py')",
                "import runpy\nrunpy.run_path('x.py')"):
        assert loads_by_path_or_imports_tools(ast.parse(src)), src


def test_every_package_ships():
    listed = set(tomllib.loads((REPO / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"])
    found = {module_name(p) for d in ("phyir", "viewer") for p in (REPO / d).rglob("__init__.py")}
    assert found - {"viewer.shaders"} <= listed, f"add to pyproject.toml: {sorted(found - listed)}"


def test_gl_packages_are_an_extra():
    project = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]
    gl = {"moderngl", "glfw", "imgui-bundle", "pyopengl"}

    def names(reqs):
        return {r.split(">")[0].split("=")[0].split("<")[0].strip().lower() for r in reqs}
    assert not names(project["dependencies"]) & gl
    assert names(project["optional-dependencies"]["viewer"]) >= gl


BLOCK_GL = f"""
import importlib, importlib.abc, pkgutil, sys
class NoGL(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] in {GL_MODULES[1:]!r}:
            raise ModuleNotFoundError(f"No module named {{name!r}} (blocked: GL not installed)")
sys.meta_path.insert(0, NoGL())
import phyir
for m in pkgutil.walk_packages(phyir.__path__, "phyir."):
    if not m.name.endswith("__main__"):
        importlib.import_module(m.name)
from phyir.cli import main
for cmd in ("info", "synth", "train", "predict", "eval", "bench", "insert"):
    try:
        main([cmd, "--help"])
    except SystemExit as e:
        assert e.code == 0, (cmd, e.code)
assert not any(m.split(".")[0] in {GL_MODULES[1:]!r} for m in sys.modules)
# the GL command says what is missing, in one line
assert main(["insert", "x.hdr", "--object", "sphere", "--at", "1,1", "-o", "y.exr"]) == 2
print("ok")
"""


@pytest.mark.slow
def test_the_library_and_its_commands_work_without_gl_installed():
    out = subprocess.run([sys.executable, "-c", BLOCK_GL], capture_output=True, text=True, cwd=REPO,
                         timeout=300)
    assert out.returncode == 0, out.stderr[-3000:]
    assert out.stdout.strip().endswith("ok")
    assert "phyir insert: error:" in out.stderr and "phyir[viewer]" in out.stderr, out.stderr[-2000:]


def file_import_graph(*dirs: str) -> dict[str, set[str]]:
    """module -> the project modules (files) it imports, lazy and type-checking imports included
    (``from pkg import name`` counts as ``pkg.name`` where that is a module, else ``pkg``)."""
    files = {module_name(p): p for p in sources(*dirs)}
    graph: dict[str, set[str]] = {}
    for mod, path in files.items():
        deps = set()
        for _, m in imported_modules(ast.parse(path.read_text())):
            target = m if m in files else m.rpartition(".")[0]
            if target in files and target != mod:
                deps.add(target)
        graph[mod] = deps
    return graph


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    out: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in graph.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def test_no_circle_of_files():
    found = cycles(file_import_graph("phyir", "viewer"))
    assert found == [], found


def test_the_app_is_made_of_collaborators_not_mixins():
    """The viewer's App owns its parts (images, display, camera, pins, ...) instead of inheriting
    them: at most one project class besides itself in its method resolution order."""
    pytest.importorskip("moderngl")
    from viewer.app.core import App

    project = [c for c in App.__mro__ if c.__module__.startswith("viewer")]
    assert App in project and len(project) <= 2, project


def test_the_circle_finder_finds_circles():
    assert cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert cycles({"a": {"b"}, "b": set()}) == []
