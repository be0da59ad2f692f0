"""Name → estimator class registry (case-insensitive), with third-party entry points.

Built-ins register here; plugins declare an entry point in the group ``iblbench.estimators``
whose object is an :class:`~iblbench.estimators.base.Estimator` subclass.
"""
from __future__ import annotations

import ast
import functools
import importlib
import warnings
from importlib.metadata import entry_points
from importlib.resources import files
from typing import TYPE_CHECKING

from iblbench.scenes.errors import InputError

if TYPE_CHECKING:
    from iblbench.estimators.base import Estimator

ENTRY_POINT_GROUP = "iblbench.estimators"
# Built-in estimators: module of iblbench.estimators -> class. They are imported on first use
# (NumPy and OpenCL with them), so that listing them, from their source, answers at once.
_BUILTINS = {"uniform": "Uniform", "balanced": "Balanced", "balanced_mis": "BalancedMIS",
             "havran": "Havran", "bis": "BIS", "smc": "SMC", "brdf": "Brdf", "envmap": "Envmap",
             "hierarchical": "Hierarchical", "fis": "Fis", "restir": "ReSTIR", "product": "Product"}
_registry: dict[str, type[Estimator]] = {}


def register(cls: type[Estimator]) -> type[Estimator]:
    """Register an estimator class under ``cls.name`` (usable as a class decorator)."""
    from iblbench.estimators.base import Estimator

    if not (isinstance(cls, type) and issubclass(cls, Estimator) and cls.name):
        raise TypeError(f"{cls!r} is not an Estimator subclass with a name")
    _registry[cls.name.lower()] = cls
    return cls


def estimator_docstrings() -> dict[str, str]:
    """Name -> class docstring of every estimator, sorted by name. The built-ins' are read from
    their source without importing them (a class body's ``__doc__ = __doc__`` is the module's
    docstring); plugins and classes registered at run time are loaded."""
    docs = {}
    for module, class_name in _BUILTINS.items():
        tree = ast.parse(files("iblbench.estimators").joinpath(f"{module}.py").read_text("utf-8"))
        node = next(n for n in tree.body if isinstance(n, ast.ClassDef) and n.name == class_name)
        assigned = {target.id: statement.value for statement in node.body
                    if isinstance(statement, ast.Assign) for target in statement.targets
                    if isinstance(target, ast.Name)}
        own = ast.get_docstring(node, clean=False)
        module_doc = isinstance(assigned.get("__doc__"), ast.Name) and assigned["__doc__"].id == "__doc__"
        docs[assigned["name"].value.lower()] = own or (ast.get_docstring(tree, clean=False)
                                                       if module_doc else None) or ""
    if _registry or any(True for _ in entry_points(group=ENTRY_POINT_GROUP)):
        docs.update((name, get_estimator_class(name).__doc__ or "") for name in estimator_names())
    return dict(sorted(docs.items()))


@functools.lru_cache(maxsize=1)
def _load_all() -> None:
    for module, class_name in _BUILTINS.items():
        register(getattr(importlib.import_module(f"iblbench.estimators.{module}"), class_name))
    for entry in entry_points(group=ENTRY_POINT_GROUP):
        try:
            register(entry.load())
        except Exception as error:   # one broken plugin must not disable the others
            warnings.warn(f"iblbench: skipping estimator plugin '{entry.name}' ({entry.value}): "
                          f"{error}", stacklevel=2)


def estimator_names() -> list[str]:
    _load_all()
    return sorted(_registry)


def get_estimator_class(name: str) -> type[Estimator]:
    _load_all()
    try:
        return _registry[name.lower()]
    except KeyError:
        raise InputError(None, f"unknown estimator '{name}'; valid estimators: "
                               f"{', '.join(estimator_names())}") from None


def make_estimator(name: str, **params) -> Estimator:
    return get_estimator_class(name)(**params)
