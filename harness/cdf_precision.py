"""Documented entry point ``python -m iblbench.harness.cdf_precision`` (docs/commands.md): the study lives
in :mod:`iblbench.harness.verify.cdf_precision`."""
from iblbench.harness.verify.cdf_precision import *  # noqa: F401,F403
from iblbench.harness.verify.cdf_precision import main

if __name__ == "__main__":
    main()
