"""neoedit: NeRF it once, edit it many times.

Public entry points live in the sub-packages (``neoedit.data``, ``neoedit.sim``, ...);
the command line is ``neo`` (``neoedit.cli``).
"""

from neoedit.errors import NeoError
from neoedit.utils.threads import set_wait_policy

# before torch and numba load their OpenMP runtimes (see neoedit.utils.threads)
set_wait_policy()

__all__ = ["NeoError", "__version__"]
__version__ = "0.1.0"
