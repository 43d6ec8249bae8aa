"""The layout the docs promise (docs/layout.md): three one-way layers, modules small enough to read,
and a wheel that holds the algorithm and the traffic application, never a research harness.

* ``sb3_ua2c``: the algorithm. Imports neither ``envs`` nor ``experiments``, with no exception.
* ``envs``: the traffic application, with the traffic job's command line (``python -m envs``).
  May import ``sb3_ua2c``, never ``experiments``.
* ``experiments``: the research harnesses of a checkout, outside the wheel. May import both.

No import cycle exists between the modules of the three packages.
"""

import ast
import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
MAX_MODULE_LINES = 800
PACKAGES = ("sb3_ua2c", "envs", "experiments")
MODULES = sorted(p for pkg in PACKAGES for p in (ROOT / pkg).rglob("*.py"))
#: Top-level modules a layer must never import (anywhere in a module, lazily or not).
FORBIDDEN = {
    "sb3_ua2c": {"envs", "experiments", "libsumo", "traci", "sumolib", "ray", "d3rlpy", "rliable", "ogbench"},
    "envs": {"experiments", "ray", "d3rlpy", "rliable", "ogbench"},
    "experiments": set(),
}
#: Modules that ``import sb3_ua2c`` / ``import envs`` must not load.
HEAVY = ("envs", "experiments", "libsumo", "traci", "sumolib", "ray", "d3rlpy", "rliable", "ogbench", "minari",
         "optuna", "rl_zoo3")


def _rel(path: Path) -> str:
    return str(path.relative_to(ROOT))


def imported_modules(source: str, package: str | None = None) -> set[str]:
    """Every module an ``import`` or ``from ... import`` statement names, anywhere in ``source``
    (relative imports resolved against ``package``)."""
    names = set()
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            names |= {alias.name for alias in node.names}
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = (package or "").split(".")
                base = base[: len(base) - node.level + 1]
                names.add(".".join([*base, node.module] if node.module else base))
            elif node.module:
                names.add(node.module)
    return names


def _package_of(path: Path) -> str:
    parts = path.relative_to(ROOT).with_suffix("").parts
    return ".".join(parts if path.name == "__init__.py" else parts[:-1])


def test_the_tree_has_modules() -> None:
    assert {p.relative_to(ROOT).parts[0] for p in MODULES} == set(PACKAGES)
    assert len(MODULES) > 60


def test_imported_modules_sees_lazy_and_relative_imports() -> None:
    source = "import os\ndef f():\n    from envs.wrappers import X\n    from . import sibling\n    from ..b import c\n"
    assert imported_modules(source, "sb3_ua2c.sub") == {"os", "envs.wrappers", "sb3_ua2c.sub", "sb3_ua2c.b"}


@pytest.mark.parametrize("path", MODULES, ids=_rel)
def test_module_length(path: Path) -> None:
    n_lines = len(path.read_text(encoding="utf-8").splitlines())
    assert n_lines <= MAX_MODULE_LINES, f"{_rel(path)} has {n_lines} lines (> {MAX_MODULE_LINES})"


@pytest.mark.parametrize("path", MODULES, ids=_rel)
def test_layers_import_one_way(path: Path) -> None:
    layer = path.relative_to(ROOT).parts[0]
    tops = {name.split(".")[0] for name in imported_modules(path.read_text(encoding="utf-8"), _package_of(path))}
    assert not tops & FORBIDDEN[layer], f"{_rel(path)} imports {sorted(tops & FORBIDDEN[layer])} (layer {layer})"


def test_the_algorithm_has_no_command_line_of_the_traffic_job() -> None:
    assert not (ROOT / "sb3_ua2c" / "__main__.py").exists()
    assert (ROOT / "envs" / "__main__.py").is_file()


def _module_name(path: Path) -> str:
    parts = path.relative_to(ROOT).with_suffix("").parts
    return ".".join(parts[:-1] if path.name == "__init__.py" else parts)


def import_edges(source: str, package: str, modules: set[str]) -> set[str]:
    """The modules of ``modules`` that ``source`` imports, anywhere (lazily or not): ``import a.b`` and
    ``from a.b import c`` name ``a.b``, or ``a.b.c`` when that is a module of ``modules``; relative
    imports are resolved against ``package``. Importing ``a.b`` also runs ``a/__init__.py``; that
    implicit edge to a parent package is not counted (every submodule would close a cycle with it)."""
    names = set()
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            names |= {alias.name for alias in node.names}
        elif isinstance(node, ast.ImportFrom):
            (base,) = imported_modules(ast.unparse(node), package)
            names |= {f"{base}.{alias.name}" if f"{base}.{alias.name}" in modules else base for alias in node.names}
    return names & modules


def import_graph(paths: list[Path]) -> dict[str, set[str]]:
    """Module name -> the modules it imports (:func:`import_edges`), over ``paths``."""
    names = {_module_name(p): p for p in paths}
    return {name: import_edges(p.read_text(encoding="utf-8"), _package_of(p), set(names)) - {name}
            for name, p in names.items()}


def find_cycle(graph: dict[str, set[str]]) -> list[str]:
    """One import cycle of ``graph`` (``[a, b, ..., a]``), or ``[]`` when it is acyclic (depth-first search)."""
    state: dict[str, int] = {}  # 1: on the current path, 2: done
    path: list[str] = []

    def visit(node: str) -> list[str]:
        state[node] = 1
        path.append(node)
        for nxt in sorted(graph.get(node, ())):
            if state.get(nxt) == 1:
                return [*path[path.index(nxt):], nxt]
            if nxt not in state and (cycle := visit(nxt)):
                return cycle
        state[node] = 2
        path.pop()
        return []

    for node in sorted(graph):
        if node not in state and (cycle := visit(node)):
            return cycle
    return []


def test_find_cycle_by_hand() -> None:
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": set()}) == []
    assert find_cycle({"a": {"b", "c"}, "b": {"d"}, "c": {"d"}, "d": set()}) == []  # a diamond is no cycle
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert find_cycle({"x": set(), "p": {"q"}, "q": {"q2"}, "q2": {"p"}}) == ["p", "q", "q2", "p"]


def test_import_edges_by_hand() -> None:
    modules = {"pkg", "pkg.a", "pkg.b", "pkg.sub", "pkg.sub.c"}
    source = "import os\nfrom pkg import a, NAME\nfrom . import c\ndef f():\n    import pkg.b\n"
    assert import_edges(source, "pkg.sub", modules) == {"pkg", "pkg.a", "pkg.sub.c", "pkg.b"}
    assert import_edges("from ..b import X\nfrom .c import Y\n", "pkg.sub", modules) == {"pkg.b", "pkg.sub.c"}


def test_no_import_cycle_between_modules() -> None:
    graph = import_graph(MODULES)
    assert sum(map(len, graph.values())) > 150  # the walk sees the tree's imports
    assert graph["envs.cli"] >= {"envs.collection", "sb3_ua2c.pipeline"}
    assert find_cycle(graph) == [], " -> ".join(find_cycle(graph))


@pytest.mark.parametrize("package", ["sb3_ua2c", "envs"])
def test_importing_a_package_loads_no_heavy_module(package: str) -> None:
    code = (f"import sys, {package}; "
            f"print(sorted({{m.split('.')[0] for m in sys.modules}} & set({HEAVY!r}) - {{{package!r}}}))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=ROOT)
    assert out.stdout.strip() == "[]", f"import {package} loads {out.stdout.strip()}"


def test_the_wheel_holds_the_algorithm_and_the_application_only(tmp_path: Path) -> None:
    """Build the wheel from a copy of the tree (no stale ``build/``) and list its top-level entries."""
    src = tmp_path / "src"
    shutil.copytree(ROOT, src, ignore=shutil.ignore_patterns(
        ".git", ".venv", "build", "dist", "*.egg-info", "__pycache__", "results", "runs", ".*_cache"))
    env = {k: v for k, v in os.environ.items() if not k.startswith("PIP_")}
    subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-q", "-w",
                    str(tmp_path / "wheel"), str(src)], check=True, capture_output=True, env=env)
    (wheel,) = (tmp_path / "wheel").glob("*.whl")
    names = zipfile.ZipFile(wheel).namelist()
    tops = {n.split("/")[0] for n in names if not n.split("/")[0].endswith(".dist-info")}
    assert tops == {"sb3_ua2c", "envs"}
    assert "envs/data/style_classifier.pt" in names and "sb3_ua2c/ua2c.py" in names
    assert not [n for n in names if "experiments" in n.split("/") or n.startswith(("tests/", "benchmarks/"))]
    (entry_points,) = [n for n in names if n.endswith(".dist-info/entry_points.txt")]
    scripts = zipfile.ZipFile(wheel).read(entry_points).decode()
    assert "ua2c = envs.cli:main" in scripts and "ua2c-zoo = sb3_ua2c.zoo:main" in scripts
