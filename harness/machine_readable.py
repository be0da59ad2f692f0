from iblbench.harness.protocol import machine_readable as _documents
from iblbench.harness.protocol.machine_readable import *  # noqa: F401,F403

# `iblbench --help` points at iblbench.harness.machine_readable for the --json schemas: they are
# those of iblbench.harness.protocol.machine_readable.
__doc__ = _documents.__doc__
