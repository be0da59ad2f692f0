"""The layers of ARCHITECTURE.md, read from the sources: Python imports by an AST walk and
OpenCL ``#include`` lines.

The packages are those of pyproject's ``[tool.setuptools.package-dir]``, so a new folder listed
there is walked.  Each package has an allow-list (:data:`ALLOWED`: the packages it may import),
and a module of a package without one fails.  Every ``import`` and ``from ... import`` counts, at
module level or inside a function (a lazy import runs back up as much as an eager one), and so
does ``import_module("iblbench....")`` (or ``__import__``) of a literal name, or of an f-string
whose constant start names a package (``f"iblbench.commands.{name}"``: ``iblbench.commands``).
A ``.cl`` file belongs to the package of its folder and may include only the kernels of packages
that package may import; an include resolves as ``Compute.program`` builds it (the kernel's own
folder, then the shared kernels' folder).  No two files may import each other through any chain."""
from __future__ import annotations

import ast
import os
import pathlib
import re
import sys

import pytest

if sys.version_info >= (3, 11):
    import tomllib
else:   # pragma: no cover
    import tomli as tomllib

ROOT = pathlib.Path(__file__).resolve().parents[1]
# The shared kernels' package: its folder is searched after a kernel's own (the device's
# include_dirs).  When the lead moves it under estimators/runtime, this line alone changes.
SHARED_KERNELS = "iblbench.estimators.runtime.kernels"

# The layers, bottom up: scenes <- estimators/runtime <- estimators <- harness/protocol <-
# harness/verify, harness/studies <- reports <- api.  Each set holds a layer and all below it;
# a package in a set allows its subpackages too.
FOUNDATION = {"iblbench.foundation"}   # errors, atomic writes, TOML: imports nothing of ours
SCENES = FOUNDATION | {"iblbench.scenes"}
RUNTIME = SCENES | {"iblbench.estimators.runtime"}
ESTIMATORS = RUNTIME | {"iblbench.estimators"}
PROTOCOL = ESTIMATORS | {"iblbench.harness.protocol"}
VERIFY = PROTOCOL | {"iblbench.harness.verify"}
STUDIES = VERIFY | {"iblbench.harness.studies"}
HARNESS = STUDIES | {"iblbench.harness"}   # harness/ itself: shims over the layers below
# The report reads only the run folder: the harness (its results store, statistics and
# rankings), and of the scenes only the modules that load, trace and open nothing.
REPORTS = {"iblbench.harness", "iblbench.reports", "iblbench.foundation.errors",
           "iblbench.foundation.atomic", "iblbench.scenes.imageio", "iblbench.scenes.cubemap"}
API = {"iblbench"}   # the package `iblbench` is api/; it may import every package
# Package -> the packages its modules (and its .cl kernels) may import.  A package that holds
# no module (configs, templates, data) needs none.
ALLOWED = {
    "iblbench.foundation": FOUNDATION,
    "iblbench.scenes": SCENES,
    "iblbench.estimators.runtime": RUNTIME,
    SHARED_KERNELS: {SHARED_KERNELS},
    "iblbench.estimators": ESTIMATORS,
    "iblbench.harness.protocol": PROTOCOL,
    "iblbench.harness.verify": VERIFY,
    "iblbench.harness.studies": STUDIES,
    "iblbench.harness": HARNESS,
    "iblbench.reports": REPORTS,
    "iblbench.commands": API,
    "iblbench": API,
}
DYNAMIC = {"import_module", "__import__"}   # importlib.import_module, import_module, __import__
INCLUDE = re.compile(r'^\s*#\s*include\s+"([^"]+)"', re.M)   # <...>: pyopencl's, not ours


def cl_include_dirs(root: pathlib.Path = ROOT) -> tuple[pathlib.Path, ...]:
    """The folders a kernel's includes are searched in after its own."""
    return (package_dirs(root)[SHARED_KERNELS],)


def allows(allowed: set[str], package: str) -> bool:
    """Whether the allow-list ``allowed`` holds ``package`` or a package above it."""
    return any(package == p or package.startswith(p + ".") for p in allowed)


def package_dirs(root: pathlib.Path = ROOT) -> dict[str, pathlib.Path]:
    """Package -> its folder, as pyproject's ``[tool.setuptools.package-dir]`` maps them."""
    with open(root / "pyproject.toml", "rb") as file:
        mapping = tomllib.load(file)["tool"]["setuptools"]["package-dir"]
    return {package: root / folder for package, folder in mapping.items()}


def package_of(name: str, packages) -> str | None:
    """The most specific of ``packages`` that holds module ``name``."""
    return max((p for p in packages if name == p or name.startswith(p + ".")), key=len,
               default=None)


def module_files(root: pathlib.Path = ROOT) -> dict[str, pathlib.Path]:
    """Dotted module name -> source file, for every ``.py`` file of every package's folder."""
    modules = {}
    for package, folder in package_dirs(root).items():
        for path in sorted(folder.glob("*.py")):
            modules[package if path.stem == "__init__" else f"{package}.{path.stem}"] = path
    return modules


def _dynamic_target(call: ast.Call) -> str | None:
    """The module an ``import_module``/``__import__`` call names by a literal, or the package
    an f-string's constant start names (up to its last dot); None for any other call."""
    function = call.func
    name = function.attr if isinstance(function, ast.Attribute) else getattr(function, "id", None)
    if name not in DYNAMIC or not call.args:
        return None
    first = call.args[0]
    if isinstance(first, ast.Constant) and isinstance(first.value, str):
        return first.value
    if (isinstance(first, ast.JoinedStr) and first.values
            and isinstance(first.values[0], ast.Constant)):
        return first.values[0].value.rpartition(".")[0] or None
    return None


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
        elif isinstance(node, ast.Call) and _dynamic_target(node):
            found.add(_dynamic_target(node))
    return {m for m in found if m == "iblbench" or m.startswith("iblbench.")}


def import_graph(root: pathlib.Path = ROOT) -> dict[str, set[str]]:
    modules = module_files(root)
    return {name: imports_of(name, path.read_text(encoding="utf-8"), path.name == "__init__.py",
                             modules)
            for name, path in modules.items()}


def include_graph(root: pathlib.Path = ROOT) -> dict[str, set[str]]:
    """Each ``.cl`` file of a package folder (relative to ``root``) -> the files of the tree it
    includes: from its own folder first, then from :func:`cl_include_dirs`."""
    graph = {}
    for folder in package_dirs(root).values():
        for path in sorted(folder.glob("*.cl")):
            included = set()
            for name in INCLUDE.findall(path.read_text(encoding="utf-8")):
                for base in (path.parent, *cl_include_dirs(root)):
                    if (base / name).is_file():
                        included.add((base / name).resolve().relative_to(root.resolve()).as_posix())
                        break
            graph[path.relative_to(root).as_posix()] = included
    return graph


def rule_breaks(graph: dict[str, set[str]], packages, allowed=ALLOWED) -> list[str]:
    """Every import outside its package's allow-list, as 'module imports target (rule)', and
    every module of a package without an allow-list."""
    breaks = []
    for module, targets in sorted(graph.items()):
        package = package_of(module, packages)
        rule = rule_of(package, allowed)
        if rule is None:
            breaks.append(f"{module}: package {package} has no rule in ALLOWED")
            continue
        for target in sorted(targets):
            banned = package_of(target, packages)
            if not (allows(allowed[rule], banned) or allows(allowed[rule], target)):
                breaks.append(f"{module} imports {target} ({package} may not import {banned})")
    return breaks


def rule_of(package: str, allowed) -> str | None:
    """The allow-list a package follows: its own, or its nearest parent's (a subpackage stays in
    its parent's layer).  The top package ``iblbench`` (api/) lends its rule to no folder, so a
    new top-level folder needs a rule of its own."""
    return package_of(package, [p for p in allowed if p != "iblbench" or package == "iblbench"])


def include_breaks(graph: dict[str, set[str]], root: pathlib.Path = ROOT,
                   allowed=ALLOWED) -> list[str]:
    """Every ``#include`` of a kernel that its folder's package may not import, and every
    kernel of a package without an allow-list."""
    folders = {folder.resolve().relative_to(root.resolve()).as_posix(): package
               for package, folder in package_dirs(root).items()}

    def package(path: str) -> str:
        return folders[path.rpartition("/")[0]]

    breaks = []
    for path, included in sorted(graph.items()):
        rule = rule_of(package(path), allowed)
        if rule is None:
            breaks.append(f"{path}: package {package(path)} has no rule in ALLOWED")
            continue
        breaks += [f"{path} includes {target} ({package(path)} may not import "
                   f"{package(target)})"
                   for target in sorted(included)
                   if not allows(allowed[rule], package(target))]
    return breaks


def all_breaks(root: pathlib.Path = ROOT) -> list[str]:
    return (rule_breaks(import_graph(root), package_dirs(root))
            + include_breaks(include_graph(root), root))


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


@pytest.fixture(scope="module")
def includes():
    return include_graph()


def test_the_walk_sees_every_folder(graph, includes):
    assert {"iblbench.cli", "iblbench.commands.run", "iblbench.estimators.runtime.framecache",
            "iblbench.harness.protocol.runner", "iblbench.harness.verify.conformance",
            "iblbench.harness.verify.twins.crosscheck", "iblbench.harness.studies.perf",
            "iblbench.reports.perf", "iblbench.scenes.registry"} <= set(graph)
    assert "iblbench.estimators.runtime.device" in graph["iblbench.estimators.light_pool"]
    # Every folder pyproject installs exists, and every folder of .py files is one of them.
    folders = set(package_dirs().values())
    assert all(folder.is_dir() for folder in folders)
    assert {path.parent for path in module_files().values()} <= folders
    assert {path.parent for top in {f.relative_to(ROOT).parts[0] for f in folders}
            for path in (ROOT / top).rglob("*.py")} <= folders
    # The walk reads dynamic imports and includes.
    assert "iblbench.commands" in graph["iblbench.cli"]
    assert includes["estimators/product.cl"] == {"estimators/lanes.cl", "estimators/descent.cl",
                                                  "estimators/envmap.cl"}
    shared = cl_include_dirs()[0].relative_to(ROOT).as_posix()
    assert includes["estimators/uniform.cl"] == {f"{shared}/light_pool_kernels.cl"}


def test_the_include_dirs_are_the_devices():
    """:func:`cl_include_dirs` are the folders of ours the device searches after a kernel's own."""
    from iblbench.estimators.runtime.device import include_dirs

    # Ours: in the checkout, outside the environment (make test's .venv lies in the checkout).
    environment = pathlib.Path(sys.prefix).resolve()
    ours = [pathlib.Path(d).resolve() for d in include_dirs()
            if pathlib.Path(d).resolve().is_relative_to(ROOT)
            and not pathlib.Path(d).resolve().is_relative_to(environment)]
    assert ours == [d.resolve() for d in cl_include_dirs()]


def test_no_import_or_include_runs_back_up():
    """Each package imports (and includes) only what its allow-list names: scenes only scenes;
    the runtime itself and scenes; estimators no harness, reports or API; the protocol never
    verify or studies, verify never studies; reports only the harness and the scene modules that
    load nothing, never an estimator or the API; the ground floor nothing."""
    assert all_breaks() == []


def test_no_import_cycles_between_files(graph):
    assert cycles(graph) == []


@pytest.mark.parametrize("module, planted", [
    ("iblbench.estimators.uniform", "from iblbench.harness.protocol import metrics"),
    ("iblbench.estimators.runtime.framecache", "from iblbench.estimators import light_pool"),
    ("iblbench.harness.verify.stress", "    from iblbench.reports.report import stress_html"),
    ("iblbench.harness.protocol.runner", "import iblbench.cli"),
    ("iblbench.reports.perf", "from iblbench.commands import perf"),
    ("iblbench.scenes.registry", "    importlib.import_module('iblbench.estimators.uniform')"),
    ("iblbench.harness.protocol.runner", "    import_module('iblbench.harness.verify.stress')"),
    ("iblbench.estimators.registry", "    __import__('iblbench.harness.protocol.runner')"),
    ("iblbench.harness.studies.perf", "    import_module(f'iblbench.reports.{name}')"),
    ("iblbench.reports.report", "    from iblbench.estimators.runtime.device import get_compute"),
    ("iblbench.reports.sample_picture", "from iblbench.estimators.light_pool import PoolEstimator"),
    ("iblbench.reports.report", "from iblbench.scenes.registry import load_scene"),
    ("iblbench.reports.report", "from iblbench.scenes import gbuffer"),
])
def test_a_planted_import_running_back_up_is_caught(graph, module, planted):
    planted_graph = {name: set(targets) for name, targets in graph.items()}
    source = "def f():\n" + planted if planted.startswith(" ") else planted
    planted_graph[module] |= imports_of(module, source, False, graph)
    assert [b for b in rule_breaks(planted_graph, package_dirs()) if b.startswith(module + " ")]


def test_a_dynamic_import_of_a_computed_name_is_not_guessed():
    """Only a literal name, or an f-string's constant start, names what is imported."""
    source = ("import importlib\nname = 'x'\nimportlib.import_module(name)\n"
              "importlib.import_module(f'{name}.y')\nprint('iblbench.reports')\n")
    assert imports_of("iblbench.scenes.x", source, False, {}) == set()


def _tree(tmp_path: pathlib.Path, extra_package_dirs: str = "") -> pathlib.Path:
    """A tmp tree with this pyproject.toml, ``extra_package_dirs`` added to its package-dir."""
    text = (ROOT / "pyproject.toml").read_text(encoding="utf-8")
    header = "[tool.setuptools.package-dir]\n"
    assert header in text
    (tmp_path / "pyproject.toml").write_text(text.replace(header, header + extra_package_dirs),
                                             encoding="utf-8")
    return tmp_path


def test_a_new_top_level_folder_is_walked_and_needs_a_rule(tmp_path):
    root = _tree(tmp_path, '"iblbench.plugins" = "plugins"\n')
    (root / "plugins").mkdir()
    (root / "plugins" / "sky.py").write_text("from iblbench.commands import run\n")
    assert all_breaks(root) == ["iblbench.plugins.sky: package iblbench.plugins has no rule in "
                                "ALLOWED"]
    # Given a rule (the scenes' floor), its import back up is a break.
    ruled = ALLOWED | {"iblbench.plugins": SCENES | {"iblbench.plugins"}}
    assert rule_breaks(import_graph(root), package_dirs(root), ruled) == [
        "iblbench.plugins.sky imports iblbench.commands (iblbench.plugins may not import "
        "iblbench.commands)"]


def test_a_planted_include_running_back_up_is_caught(tmp_path):
    """A runtime kernel that includes an estimator's, and a shared kernel that does: both
    caught; the same include from an estimator's kernel is not."""
    root = _tree(tmp_path)
    shared = cl_include_dirs(root)[0]
    for folder in (root / "estimators", root / "estimators" / "runtime", shared):
        folder.mkdir(parents=True, exist_ok=True)
    (root / "estimators" / "envmap.cl").write_text('#include "lanes.cl"\n')
    (root / "estimators" / "lanes.cl").write_text('#include "common.cl"\n')
    (shared / "common.cl").write_text("#include <philox.cl>\n")
    (root / "estimators" / "runtime" / "mips.cl").write_text('  #  include "../envmap.cl"\n')
    (shared / "light_pool.cl").write_text(
        f'#include "{os.path.relpath(root / "estimators" / "lanes.cl", shared)}"\n')
    shared_name = shared.relative_to(root).as_posix()
    assert include_breaks(include_graph(root), root) == sorted([
        f"{shared_name}/light_pool.cl includes estimators/lanes.cl "
        f"({SHARED_KERNELS} may not import iblbench.estimators)",
        "estimators/runtime/mips.cl includes estimators/envmap.cl "
        "(iblbench.estimators.runtime may not import iblbench.estimators)"])


def test_a_planted_cycle_is_caught(graph):
    planted = {name: set(targets) for name, targets in graph.items()}
    planted["iblbench.harness.protocol.timing"].add("iblbench.harness.protocol.runner")
    assert ["iblbench.harness.protocol.runner", "iblbench.harness.protocol.timing"] in [
        [m for m in c if m in ("iblbench.harness.protocol.runner", "iblbench.harness.protocol.timing")]
        for c in cycles(planted)]


MAX_FUNCTION_LINES = 80   # ARCHITECTURE.md's invariant: a longer function is split


def long_functions(paths) -> list[str]:
    """'path: name (N lines)' for every function (or method) over MAX_FUNCTION_LINES."""
    found = []
    for path in paths:
        for node in ast.walk(ast.parse(pathlib.Path(path).read_text(encoding="utf-8"))):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                lines = node.end_lineno - node.lineno + 1
                if lines > MAX_FUNCTION_LINES:
                    found.append(f"{path}: {node.name} ({lines} lines)")
    return found


def test_no_function_is_over_80_lines():
    assert long_functions(module_files().values()) == []


def test_a_planted_long_function_is_caught(tmp_path):
    body = "".join(f"    x{i} = {i}\n" for i in range(MAX_FUNCTION_LINES))
    (tmp_path / "long.py").write_text(f"def long():\n{body}\n\ndef short():\n    return 1\n")
    assert long_functions([tmp_path / "long.py"]) == [
        f"{tmp_path / 'long.py'}: long ({MAX_FUNCTION_LINES + 1} lines)"]


def test_importing_the_report_loads_no_device_estimator_or_tracer():
    """The allow-lists see direct imports; this sees the chain: the report's modules, imported
    in a fresh interpreter, bring in no OpenCL, no estimator and no G-buffer tracer."""
    import subprocess
    import sys as interpreter

    probe = ("import sys, iblbench.reports.report, iblbench.reports.images\n"
             "print(sorted(m for m in sys.modules if m == 'pyopencl' or m == 'embreex'\n"
             "             or m.startswith(('iblbench.estimators', 'iblbench.scenes.gbuffer'))))")
    done = subprocess.run([interpreter.executable, "-c", probe], capture_output=True, text=True,
                          timeout=120)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "[]"
