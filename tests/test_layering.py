"""The house rules (docs/architecture.md), checked on the source so they stay true.

* ``phyir`` never imports GL or the app, lazily or not, and works with the GL packages absent;
* each package imports only packages of its own layer or below;
* no module uses another module's private names;
* no file over 600 lines, class over 350, function over 100 (outside tests);
* no test module imports another; the GL packages are an extra, not a base dependency.
"""

from __future__ import annotations

import ast
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
    "phyir.transforms": 0, "phyir.depth_normal": 0, "phyir.gravity": 0, "phyir.plausible_geometry": 0,
    "phyir.estimators": 0,
    "phyir.io": 1, "phyir.shading": 1,
    "phyir.lighting": 2, "phyir.nets": 2, "phyir.synth": 2, "phyir.metrics": 2,
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
    parts = module.split(".")
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


def test_the_lighting_methods_are_listed_once():
    """The lighting methods are named by the registry (phyir.estimators, filled from the entry points),
    not by a tuple of their names kept in step by hand."""
    names = set(tomllib.loads((REPO / "pyproject.toml").read_text())["project"]["entry-points"]
                ["phyir.lighting_methods"])
    assert {"fused", "lnet", "projection"} <= names
    bad = []
    for p in sources(*SOURCE_DIRS):
        for node in ast.walk(ast.parse(p.read_text())):
            if isinstance(node, (ast.Tuple, ast.List, ast.Set)):
                strings = {e.value for e in node.elts if isinstance(e, ast.Constant)}
                if names <= strings:
                    bad.append(f"{p.relative_to(REPO)}:{node.lineno}: lists the lighting methods (use "
                               "phyir.estimators.lighting_methods())")
    assert not bad, "\n".join(bad)


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
