"""Where things are in a ``neo bench`` run folder, for the runner and for tools that read a
finished run (benchmarks/bench_grasp.py, bench_inpaint_ceiling.py); a kept version is an
ordinary scene (or store) that ``neo view`` / ``neo render`` open.

    OUT/REPORT.md, OUT/results.json, OUT/figures/<scene>.png
    OUT/units/sim/<scene>/scene               a simulated scene (runs without --data)
    OUT/units/train/<scene>/<scan>/scene      the trained pre scan and oracles (post*)
    OUT/units/<scene>/<method>/unit.json      a method's figures on a scene
    OUT/units/<scene>/<method>/scene          its edited version (--keep-versions)
    OUT/units/assembly/<method>/store         the assembly's chain, step_0 .. (--keep-versions)
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from neoedit.errors import NeoError


@dataclass(frozen=True)
class RunFolder:
    out: Path
    """The run folder (``neo bench --out``)."""
    data: Path | None = None
    """The reused NEO-Sim suite (``neo bench --data``; None: the run simulated its scenes)."""

    def unit_dir(self, unit_id: str) -> Path:
        return self.out / "units" / unit_id

    def scene_data(self, scene: str) -> Path:
        """The simulated scene: scene.json, pre/, post/ or post_1 .. ."""
        if self.data is not None:
            return self.data / scene
        return self.unit_dir(f"sim/{scene}") / "scene"

    def trained(self, scene: str, scan: str) -> Path:
        """The field trained on one scan ('pre': with language; 'post*': the oracles)."""
        return self.unit_dir(f"train/{scene}/{scan}") / "scene"

    def version(self, scene: str, method: str) -> Path:
        """Where ``method``'s edited version of ``scene`` is kept (the assembly: a store)."""
        return self.unit_dir(f"{scene}/{method}") / ("store" if scene == "assembly" else "scene")

    def result(self, scene: str, method: str) -> dict[str, Any]:
        """The figures of one finished unit (its ``unit.json``), or a clear error. They are
        those of the run that last finished the unit in this folder: a unit redone with other
        settings replaces its whole folder, kept version included, so the figures and
        :meth:`kept` always come from the same run."""
        try:
            unit = json.loads((self.unit_dir(f"{scene}/{method}") / "unit.json").read_text())
            return dict(unit["result"])
        except (OSError, ValueError, KeyError, TypeError):
            raise NeoError(
                f"{self.out} has no finished {scene}/{method} unit (re-run your neo bench "
                f"command with --out {self.out} --scenes {scene} --methods {method})"
            ) from None

    def kept(self, scene: str, method: str) -> Path:
        """:meth:`version`, or a clear error when the run did not keep it."""
        path = self.version(scene, method)
        if not path.exists():
            raise NeoError(
                f"{path} does not exist: re-run your neo bench command with --out {self.out} "
                f"--scenes {scene} --methods {method} --keep-versions"
            )
        return path
