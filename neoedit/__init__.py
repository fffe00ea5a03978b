"""neoedit: NeRF it once, edit it many times.

Public entry points live in the sub-packages (``neoedit.data``, ``neoedit.sim``, ...);
the command line is ``neo`` (``neoedit.cli``).
"""

from neoedit.errors import NeoError

__all__ = ["NeoError", "__version__"]
__version__ = "0.1.0"
