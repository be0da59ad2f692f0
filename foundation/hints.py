"""Whether a value is of a type hint, and the hint in words: the Python API checks each
argument against its field's or parameter's hint, so that a wrong type is an InputError naming
the argument (issue 35: ``device=5`` and ``out=123`` raised AttributeError and TypeError, and
``force="no"`` ran as True).

The hints are those of the dataclasses and signatures: ``bool`` takes only True or False,
``int`` a whole number (not a bool), ``float`` any real number (not a bool), ``pathlib.Path``
or ``os.PathLike`` a string or a path, ``tuple[T, ...]`` and ``tuple[A, B]`` a list or a tuple
of such items, ``dict[K, V]`` a dict, a union any of its members.
"""
from __future__ import annotations

import numbers
import os
import pathlib
import reprlib
import types
import typing

from iblbench.foundation.errors import InputError

_WORDS = {bool: "True or False", int: "a whole number", float: "a number", str: "a string",
          pathlib.Path: "a path", os.PathLike: "a path", dict: "a dict", slice: "a slice",
          type(None): "None"}
_PLURALS = {int: "whole numbers", float: "numbers", str: "strings", pathlib.Path: "paths",
            os.PathLike: "paths", dict: "dicts"}
_SHORT = reprlib.Repr()
_SHORT.maxstring = _SHORT.maxother = 80


def fits(value, hint) -> bool:
    """Whether ``value`` is of type ``hint`` (module docstring)."""
    origin, args = typing.get_origin(hint), typing.get_args(hint)
    if hint is typing.Any:
        return True
    if hint is None or hint is type(None):
        return value is None
    if origin in (typing.Union, types.UnionType):
        return any(fits(value, member) for member in args)
    if origin is tuple:
        if not isinstance(value, (list, tuple)):
            return False
        if len(args) == 2 and args[1] is Ellipsis:
            return all(fits(item, args[0]) for item in value)
        return len(value) == len(args) and all(map(fits, value, args))
    if origin is dict:
        return isinstance(value, dict) and all(fits(k, args[0]) and fits(v, args[1])
                                               for k, v in value.items())
    if hint is int:
        return isinstance(value, numbers.Integral) and not isinstance(value, bool)
    if hint is float:
        return isinstance(value, numbers.Real) and not isinstance(value, bool)
    if hint in (pathlib.Path, os.PathLike):
        return isinstance(value, (str, os.PathLike))
    return isinstance(value, origin or hint)


def in_words(hint) -> str:
    """``hint`` as a message says it: ``str | tuple[str, ...]`` is "a string or a list of
    strings"."""
    origin, args = typing.get_origin(hint), typing.get_args(hint)
    if origin in (typing.Union, types.UnionType):   # bool | None: "True, False or None"
        words = [word for member in args for word in (
            ("True", "False") if member is bool else (in_words(member),))]
        return ", ".join(words[:-1]) + " or " + words[-1]
    if origin is tuple:
        if len(args) == 2 and args[1] is Ellipsis:
            return f"a list of {_plural(args[0])}"
        if len(set(args)) == 1:
            return f"a list of {len(args)} {_plural(args[0])}"
        return "a list (" + ", ".join(map(in_words, args)) + ")"
    if origin is dict:
        return f"a dict of {_plural(args[1])}"
    return _WORDS.get(hint, getattr(hint, "__name__", str(hint)))


def _plural(hint) -> str:
    if typing.get_origin(hint) in (typing.Union, types.UnionType):
        words = [_plural(member) for member in typing.get_args(hint)]
        return ", ".join(words[:-1]) + " or " + words[-1]
    return _PLURALS.get(hint) or f"items each {in_words(hint)}"


def check_type(name: str, value, hint) -> None:
    """An InputError naming argument ``name`` if ``value`` is not of type ``hint``."""
    if not fits(value, hint):
        raise InputError(None, f"{name} must be {in_words(hint)}, got {_SHORT.repr(value)}")
