"""Reading the TOML files users write (scenes, sweeps, budgets) with one-line errors."""
from __future__ import annotations

import os
import sys

from iblbench.foundation.errors import InputError

if sys.version_info >= (3, 11):
    import tomllib
else:   # pragma: no cover
    import tomli as tomllib


def read_toml(path: str | os.PathLike, kind: str) -> dict:
    """The parsed document; an :class:`InputError` naming the file if it cannot be read.

    ``kind`` names the file in messages, e.g. "scene file" → "scene file not found".
    """
    try:
        with open(path, "rb") as handle:
            return tomllib.load(handle)
    except FileNotFoundError:
        raise InputError(path, f"{kind} not found") from None
    except IsADirectoryError:
        raise InputError(path, f"{kind} is a directory, not a .toml file") from None
    except tomllib.TOMLDecodeError as error:
        raise InputError(path, f"TOML syntax error: {error}") from None
    except (OSError, UnicodeDecodeError) as error:
        raise InputError(path, f"cannot read {kind}: {error}") from None
