"""The import rules of ARCHITECTURE.md, read from the sources by an AST walk.

Every ``import`` and ``from ... import`` counts, at module level or inside a function (a lazy
import runs back up as much as an eager one).  The folders are the packages of pyproject's
``package-dir``; each rule names the packages a folder may not import, and no two files may
import each other through any chain (no import cycles between files)."""
from __future__ import annotations

import ast
import pathlib

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1]
# Source folder -> package, as pyproject's [tool.setuptools.package-dir] maps them.
FOLDERS = {"api": "iblbench", "estimators": "iblbench.estimators", "scenes": "iblbench.scenes",
           "harness": "iblbench.harness", "reports": "iblbench.reports"}
API = ("iblbench", "iblbench.cli", "iblbench.commands")   # the package `iblbench` is api/
# Package (and everything under it) -> the packages it must never import.
FORBIDDEN = {
    "iblbench.scenes": ("iblbench.estimators", "iblbench.harness", "iblbench.reports", *API),
    "iblbench.estimators.runtime": ("iblbench.estimators", "iblbench.harness", "iblbench.reports",
                                    *API),
    "iblbench.estimators": ("iblbench.harness", "iblbench.reports", *API),
    "iblbench.harness.protocol": ("iblbench.harness.verify", "iblbench.harness.studies",
                                  "iblbench.reports", *API),
    "iblbench.harness.verify": ("iblbench.harness.studies", "iblbench.reports", *API),
    "iblbench.harness": ("iblbench.reports", *API),
    # The report reads only the run folder (issue 33): no estimator, device or scene tracer.
    "iblbench.reports": ("iblbench.estimators", "iblbench.scenes", *API),
}
# The exceptions: the runtime may import itself; the reports the scenes' modules that load or
# trace nothing (errors, atomic writes, the EXR format, the cube-map layout).
ALLOWED = {"iblbench.estimators.runtime": ("iblbench.estimators.runtime",),
           "iblbench.reports": ("iblbench.scenes.errors", "iblbench.scenes.atomic",
                                "iblbench.scenes.imageio", "iblbench.scenes.cubemap")}


def module_files(root: pathlib.Path = ROOT) -> dict[str, pathlib.Path]:
    """Dotted module name -> source file, for every package folder."""
    modules = {}
    for folder, package in FOLDERS.items():
        for path in sorted((root / folder).rglob("*.py")):
            parts = path.relative_to(root / folder).with_suffix("").parts
            if parts[-1] == "__init__":
                parts = parts[:-1]
            modules[".".join((package, *parts))] = path
    return modules


def imports_of(name: str, source: str, is_package: bool, known) -> set[str]:
    """The ``iblbench`` modules that ``source`` (module ``name``) imports, anywhere in it;
    ``from package import module`` counts as an import of that module."""
    found = set()
    here = name if is_package else name.rpartition(".")[0]
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = here.split(".")[:len(here.split(".")) - node.level + 1]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module
            submodules = [f"{target}.{alias.name}" for alias in node.names
                          if f"{target}.{alias.name}" in known]
            found.update(submodules or [target])
    return {m for m in found if m == "iblbench" or m.startswith("iblbench.")}


def import_graph(root: pathlib.Path = ROOT) -> dict[str, set[str]]:
    modules = module_files(root)
    return {name: imports_of(name, path.read_text(encoding="utf-8"), path.name == "__init__.py",
                             modules)
            for name, path in modules.items()}


def _under(module: str, package: str) -> bool:
    return module == package or module.startswith(package + ".")


def rule_breaks(graph: dict[str, set[str]]) -> list[str]:
    """Every import that runs back up, as 'module imports target (rule)'."""
    breaks = []
    for module, targets in graph.items():
        # The most specific rule that covers the module.
        rule = max((p for p in FORBIDDEN if _under(module, p)), key=len, default=None)
        if rule is None:
            continue
        for target in sorted(targets):
            if any(_under(target, p) for p in ALLOWED.get(rule, ())):
                continue
            for banned in FORBIDDEN[rule]:
                # `iblbench` itself (api/__init__) is banned exactly; its subpackages by name.
                hit = target == banned if banned == "iblbench" else _under(target, banned)
                if hit:
                    breaks.append(f"{module} imports {target} ({rule} may not import {banned})")
                    break
    return breaks


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The import cycles between files: strongly connected components of two or more modules
    (or one that imports itself), by Tarjan's algorithm."""
    index, low, stack, on_stack, found = {}, {}, [], set(), []

    def visit(node):
        index[node] = low[node] = len(index)
        stack.append(node)
        on_stack.add(node)
        for target in graph.get(node, ()):
            if target not in graph:
                continue
            if target not in index:
                visit(target)
                low[node] = min(low[node], low[target])
            elif target in on_stack:
                low[node] = min(low[node], index[target])
        if low[node] == index[node]:
            component = []
            while True:
                member = stack.pop()
                on_stack.discard(member)
                component.append(member)
                if member == node:
                    break
            if len(component) > 1 or node in graph[node]:
                found.append(sorted(component))

    for node in sorted(graph):
        if node not in index:
            visit(node)
    return found


@pytest.fixture(scope="module")
def graph():
    return import_graph()


def test_the_walk_sees_every_folder(graph):
    assert {"iblbench.cli", "iblbench.estimators.runtime.framecache",
            "iblbench.harness.protocol.runner", "iblbench.harness.verify.conformance",
            "iblbench.harness.studies.perf", "iblbench.reports.perf",
            "iblbench.scenes.registry"} <= set(graph)
    assert "iblbench.estimators.runtime.device" in graph["iblbench.estimators.light_pool"]


def test_no_import_runs_back_up(graph):
    """estimators never import harness, reports or the API (the runtime: only itself and
    scenes); harness never imports reports or the API, its protocol never verify or studies,
    and verify never studies; reports never import the API, an estimator or a scene module
    but the four that load nothing; scenes import only scenes."""
    assert rule_breaks(graph) == []


def test_no_import_cycles_between_files(graph):
    assert cycles(graph) == []


@pytest.mark.parametrize("module, planted", [
    ("iblbench.estimators.uniform", "from iblbench.harness.protocol import metrics"),
    ("iblbench.estimators.runtime.framecache", "from iblbench.estimators import light_pool"),
    ("iblbench.harness.verify.stress", "    from iblbench.reports.report import stress_html"),
    ("iblbench.harness.protocol.runner", "import iblbench.cli"),
    ("iblbench.reports.perf", "from iblbench.commands import perf"),
    ("iblbench.reports.report", "    from iblbench.estimators.runtime.device import get_compute"),
    ("iblbench.reports.sample_picture", "from iblbench.estimators.light_pool import PoolEstimator"),
    ("iblbench.reports.report", "from iblbench.scenes.registry import load_scene"),
    ("iblbench.reports.report", "from iblbench.scenes import gbuffer"),
])
def test_a_planted_import_running_back_up_is_caught(graph, module, planted):
    planted_graph = {name: set(targets) for name, targets in graph.items()}
    source = "def f():\n" + planted if planted.startswith(" ") else planted
    planted_graph[module] |= imports_of(module, source, False, graph)
    assert [b for b in rule_breaks(planted_graph) if b.startswith(module + " ")]


def test_a_planted_cycle_is_caught(graph):
    planted = {name: set(targets) for name, targets in graph.items()}
    planted["iblbench.harness.protocol.timing"].add("iblbench.harness.protocol.runner")
    assert ["iblbench.harness.protocol.runner", "iblbench.harness.protocol.timing"] in [
        [m for m in c if m in ("iblbench.harness.protocol.runner", "iblbench.harness.protocol.timing")]
        for c in cycles(planted)]
