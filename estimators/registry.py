"""Name → estimator class registry (case-insensitive), filled from entry points.

Every estimator, built-in or third-party, is an entry point in the group ``iblbench.estimators``
whose object is an :class:`~iblbench.estimators.base.Estimator` subclass: the built-ins are
iblbench's own (``pyproject.toml``), a plugin's are its package's.  They are imported on first
use (NumPy and OpenCL with them), so that listing them, from their source, answers at once.
"""
from __future__ import annotations

import ast
import functools
import importlib.util
import warnings
from importlib.metadata import EntryPoint, entry_points
from pathlib import Path
from typing import TYPE_CHECKING

from iblbench.foundation.errors import InputError

if TYPE_CHECKING:
    from iblbench.estimators.base import Estimator

ENTRY_POINT_GROUP = "iblbench.estimators"
DISTRIBUTION = "iblbench"   # the distribution whose entry points are the built-ins
_registry: dict[str, type[Estimator]] = {}


def register(cls: type[Estimator]) -> type[Estimator]:
    """Register an estimator class under ``cls.name`` (usable as a class decorator)."""
    from iblbench.estimators.base import Estimator

    if not (isinstance(cls, type) and issubclass(cls, Estimator) and cls.name):
        raise TypeError(f"{cls!r} is not an Estimator subclass with a name")
    _registry[cls.name.lower()] = cls
    return cls


def is_builtin(entry: EntryPoint) -> bool:
    return entry.dist is not None and entry.dist.name == DISTRIBUTION


@functools.lru_cache(maxsize=1)
def _entry_points() -> tuple[EntryPoint, ...]:
    """The group's entry points, the built-ins first, each in its distribution's order."""
    return tuple(sorted(entry_points(group=ENTRY_POINT_GROUP), key=lambda e: not is_builtin(e)))


def builtin_names() -> list[str]:
    """The built-in estimators' names, in the installed metadata's order, which is alphabetical
    (setuptools sorts the group); read from metadata: nothing is imported."""
    return [entry.name.lower() for entry in _entry_points() if is_builtin(entry)]


def _class_source(entry: EntryPoint) -> tuple[str, str | None] | None:
    """(name, docstring) of an entry point's class read from its module's source without running
    it (a class body's ``__doc__ = __doc__`` is the module's docstring), or None where the source
    does not define the class itself (then it must be loaded)."""
    spec = importlib.util.find_spec(entry.module)   # imports the parent packages only
    if spec is None or not spec.origin or not spec.origin.endswith(".py"):
        return None
    tree = ast.parse(Path(spec.origin).read_text("utf-8"))
    node = next((n for n in tree.body if isinstance(n, ast.ClassDef) and n.name == entry.attr),
                None)
    if node is None:
        return None
    assigned = {target.id: statement.value for statement in node.body
                if isinstance(statement, ast.Assign) for target in statement.targets
                if isinstance(target, ast.Name)}
    name = assigned.get("name")
    if not (isinstance(name, ast.Constant) and isinstance(name.value, str)):
        return None
    own = ast.get_docstring(node, clean=False)
    module_doc = isinstance(assigned.get("__doc__"), ast.Name) and assigned["__doc__"].id == "__doc__"
    return name.value.lower(), own or (ast.get_docstring(tree, clean=False) if module_doc else None)


def estimator_docstrings() -> dict[str, str]:
    """Name -> class docstring of every estimator, sorted by name, read from the source without
    importing it where it can be (:func:`_class_source`); classes registered at run time and
    entry points whose class is defined elsewhere are loaded."""
    docs = {name: cls.__doc__ or "" for name, cls in _registry.items()}
    for entry in _entry_points():
        read = _class_source(entry)
        if read is None:
            cls = _load(entry)
            read = (cls.name.lower(), cls.__doc__) if cls is not None else None
        if read is not None:
            docs.setdefault(read[0], read[1] or "")
    return dict(sorted(docs.items()))


def _load(entry: EntryPoint) -> type[Estimator] | None:
    """Register an entry point's class; a broken plugin warns and is skipped."""
    try:
        return register(entry.load())
    except Exception as error:   # one broken plugin must not disable the others
        if is_builtin(entry):
            raise
        warnings.warn(f"iblbench: skipping estimator plugin '{entry.name}' ({entry.value}): "
                      f"{error}", stacklevel=3)
        return None


@functools.lru_cache(maxsize=1)
def _load_all() -> None:
    for entry in _entry_points():
        _load(entry)


def estimator_names() -> list[str]:
    _load_all()
    return sorted(_registry)


def estimator_classes() -> list[type[Estimator]]:
    """Every registered class in registration order: the built-ins in the installed
    metadata's (alphabetical) order, then the plugins', then any registered at run time."""
    _load_all()
    return list(_registry.values())


def get_estimator_class(name: str) -> type[Estimator]:
    _load_all()
    try:
        return _registry[name.lower()]
    except KeyError:
        raise InputError(None, f"unknown estimator '{name}'; valid estimators: "
                               f"{', '.join(estimator_names())}") from None


def make_estimator(name: str, **params) -> Estimator:
    return get_estimator_class(name)(**params)
