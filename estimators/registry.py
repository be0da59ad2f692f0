"""Name → estimator class registry (case-insensitive), with third-party entry points.

Built-ins register here; plugins declare an entry point in the group ``iblbench.estimators``
whose object is an :class:`~iblbench.estimators.base.Estimator` subclass.
"""
from __future__ import annotations

import functools
import warnings
from importlib.metadata import entry_points

from iblbench.estimators.balanced import Balanced
from iblbench.estimators.balanced_mis import BalancedMIS
from iblbench.estimators.base import Estimator
from iblbench.estimators.bis import BIS
from iblbench.estimators.havran import Havran
from iblbench.estimators.smc import SMC
from iblbench.estimators.uniform import Uniform
from iblbench.scenes.errors import InputError

ENTRY_POINT_GROUP = "iblbench.estimators"
_BUILTINS: tuple[type[Estimator], ...] = (Uniform, Balanced, BalancedMIS, Havran, BIS, SMC)
_registry: dict[str, type[Estimator]] = {}


def register(cls: type[Estimator]) -> type[Estimator]:
    """Register an estimator class under ``cls.name`` (usable as a class decorator)."""
    if not (isinstance(cls, type) and issubclass(cls, Estimator) and cls.name):
        raise TypeError(f"{cls!r} is not an Estimator subclass with a name")
    _registry[cls.name.lower()] = cls
    return cls


@functools.lru_cache(maxsize=1)
def _load_all() -> None:
    for cls in _BUILTINS:
        register(cls)
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
