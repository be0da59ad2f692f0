from iblbench.harness.protocol import sweep as _sweep
from iblbench.harness.protocol.sweep import *  # noqa: F401,F403

# `iblbench run --help` points at "the docstring of iblbench.harness.sweep": it is the sweep
# format of iblbench.harness.protocol.sweep.
__doc__ = _sweep.__doc__
