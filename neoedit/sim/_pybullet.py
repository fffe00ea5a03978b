"""pybullet, imported once for the simulator's modules. Its C module prints a build-time
banner on the process's stderr when it loads; ``neo`` (without ``--verbose``) sets
:data:`QUIET_ENV` and the banner is dropped, so a user sees only neoedit's own messages."""

from __future__ import annotations

import os
import sys

QUIET_ENV = "NEO_QUIET_THIRD_PARTY"


def _import_quietly():
    if os.environ.get(QUIET_ENV) != "1" or "pybullet" in sys.modules:
        import pybullet

        return pybullet
    sys.stderr.flush()
    saved, null = os.dup(2), os.open(os.devnull, os.O_WRONLY)
    os.dup2(null, 2)
    try:
        import pybullet
    finally:
        os.dup2(saved, 2)
        os.close(saved)
        os.close(null)
    return pybullet


pb = _import_quietly()
