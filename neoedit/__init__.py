"""neoedit: NeRF it once, edit it many times.

The Python facade (:mod:`neoedit.api`)::

    import neoedit as neo

    s = neo.load("outputs/demo/scene")
    s2 = s.remove("red mug")
    s3 = s2.move("duck", translate=(0.1, 0.0, 0.0))
    neo.save(s3, "outputs/demo/moved")

The sub-packages hold the rest (``neoedit.data``, ``neoedit.edit``, ``neoedit.sim``, ...);
the command line is ``neo`` (``neoedit.cli``). Exports load lazily: ``import neoedit``
does not import torch.
"""

from __future__ import annotations

from neoedit.errors import NeoError
from neoedit.utils.lazy import lazy_exports
from neoedit.utils.threads import set_wait_policy

# before torch and numba load their OpenMP runtimes (see neoedit.utils.threads)
set_wait_policy()

_EXPORTS = {
    "load": "neoedit.api",
    "save": "neoedit.api",
    "EditableScene": "neoedit.api",
    "Cameras": "neoedit.cameras",
    "OrientedBox": "neoedit.geometry",
    "RemoveConfig": "neoedit.edit.remove",
    "MoveConfig": "neoedit.edit.relocate",
    "LanguageUpdateConfig": "neoedit.edit.language_update",
    "QueryConfig": "neoedit.language.localize",
}

__all__ = ["NeoError", "__version__", *sorted(_EXPORTS)]
__version__ = "0.1.0"


__getattr__ = lazy_exports(__name__, _EXPORTS)
