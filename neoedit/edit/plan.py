"""Action plans: a list of moves and removals applied one after another, each to the
version the previous step wrote (paper Sec. III-E: "NeRF it once, edit it many times").

A plan is YAML or JSON, a list of actions (or ``{actions: [...]}``)::

    - {type: move, prompt: red mug, translate_m: [0.10, 0.05, 0.0], yaw_deg: 45}
    - {type: remove, prompt: duck}
    - {type: move, prompt: lego brick, transform: [[1,0,0,0.1],[0,1,0,0],[0,0,1,0],[0,0,0,1]]}
    - {type: move, prompt: "red mug; duck", motions: [{translate_m: [0.1, 0, 0]},
                                                      {translate_m: [0, 0.1, 0], yaw_deg: 30}]}

Each step queries the *current edited* version for its objects (``;`` separates several,
moved or removed in one edit), so a step sees where earlier steps put things. A move takes
one motion for all its objects, or ``motions`` with one per object; ``translate_m`` is in
world metres, ``yaw_deg`` turns about the vertical axis through the object's box centre,
``transform`` is a 4x4 world rigid motion (x' = T x). A step may give ``box`` (a box
mapping, or a list) instead of a prompt.
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np
import yaml
from pydantic import BaseModel, ConfigDict, ValidationError, model_validator

from neoedit.edit.inpaint import Inpainter
from neoedit.edit.relocate import Motion, MoveConfig, move
from neoedit.edit.remove import RemoveConfig, remove
from neoedit.errors import NeoError
from neoedit.geometry import OrientedBox, is_rigid, motion_about
from neoedit.scene import Scene


class MotionSpec(BaseModel):
    model_config = ConfigDict(extra="forbid")
    translate_m: tuple[float, float, float] | None = None
    yaw_deg: float = 0.0
    transform: list[list[float]] | None = None

    @model_validator(mode="after")
    def _one_kind(self) -> MotionSpec:
        if self.transform is not None:
            if self.translate_m is not None or self.yaw_deg != 0.0:
                raise ValueError("give either translate_m/yaw_deg or transform, not both")
            if not is_rigid(np.asarray(self.transform, dtype=np.float64)):
                raise ValueError(
                    "transform must be a finite 4x4 rigid motion (orthonormal rotation, det +1, "
                    "last row 0 0 0 1)"
                )
        elif self.translate_m is None and self.yaw_deg == 0.0:
            raise ValueError("a move needs a motion: translate_m [x, y, z], yaw_deg or transform")
        elif self.yaw_deg == 0.0 and not any(self.translate_m or ()):
            raise ValueError("the motion is zero: nothing would move")
        if self.translate_m is not None and not np.isfinite(self.translate_m).all():
            raise ValueError("translate_m must be finite")
        if not np.isfinite(self.yaw_deg):
            raise ValueError("yaw_deg must be finite")
        return self

    def matrix(self, box: OrientedBox) -> np.ndarray:
        if self.transform is not None:
            return np.asarray(self.transform, dtype=np.float64)
        t = np.asarray(self.translate_m or (0.0, 0.0, 0.0), dtype=np.float64)
        return motion_about(np.asarray(box.center_m), t, self.yaw_deg)


class Action(BaseModel):
    model_config = ConfigDict(extra="forbid")
    type: Literal["move", "remove"]
    prompt: str | None = None
    box: dict[str, Any] | list[dict[str, Any]] | None = None
    translate_m: tuple[float, float, float] | None = None
    yaw_deg: float = 0.0
    transform: list[list[float]] | None = None
    motions: list[MotionSpec] | None = None

    @model_validator(mode="after")
    def _consistent(self) -> Action:
        if (self.prompt is None) == (self.box is None):
            raise ValueError("give either prompt or box")
        inline = self.translate_m is not None or self.yaw_deg != 0.0 or self.transform is not None
        if self.type == "remove":
            if inline or self.motions:
                raise ValueError("a remove takes no motion")
            return self
        if self.motions is not None and inline:
            raise ValueError("give either motions or one motion, not both")
        if self.motions is not None and not self.motions:
            raise ValueError("motions is empty: give one motion per object")
        if self.prompt is not None and not self.prompt.strip():
            raise ValueError("the prompt is empty")
        if self.motions is None:
            self.motions = [
                MotionSpec(
                    translate_m=self.translate_m, yaw_deg=self.yaw_deg, transform=self.transform
                )
            ]
        return self

    @property
    def label(self) -> str:
        return f"{self.type} {self.prompt!r}" if self.prompt else f"{self.type} box"


def parse_plan(raw: Any, where: str = "plan") -> list[Action]:
    """Validated actions of a plan (a list, or a mapping with ``actions``); one clear
    NeoError naming the step and the problem otherwise."""
    if isinstance(raw, dict) and set(raw) == {"actions"}:
        raw = raw["actions"]
    if not isinstance(raw, list) or not raw:
        raise NeoError(f"{where}: a plan is a non-empty list of actions")
    actions = []
    for i, item in enumerate(raw, 1):
        try:
            actions.append(Action.model_validate(item))
        except ValidationError as e:
            err = e.errors()[0]
            loc = ".".join(str(x) for x in err["loc"]) or "step"
            msg = err["msg"].removeprefix("Value error, ")
            raise NeoError(f"{where}: step {i}: {loc}: {msg}") from None
    return actions


def load_plan(path: Path) -> list[Action]:
    path = Path(path)
    try:
        text = path.read_text()
    except FileNotFoundError:
        raise NeoError(f"plan not found: {path}") from None
    except OSError as e:
        raise NeoError(f"{path}: cannot read the plan: {e}") from None
    try:
        raw = json.loads(text) if path.suffix == ".json" else yaml.safe_load(text)
    except (json.JSONDecodeError, yaml.YAMLError) as e:
        raise NeoError(
            f"{path}: not valid {'JSON' if path.suffix == '.json' else 'YAML'}: {e}"
        ) from None
    return parse_plan(raw, str(path))


@dataclass
class PlanConfig:
    preview: bool = False
    """Run every step as an instant preview (moves composed at render time, removals cut
    without inpainting): no training."""
    move: MoveConfig = field(default_factory=MoveConfig)
    remove: RemoveConfig = field(default_factory=RemoveConfig)


def apply_action(
    scene: Scene,
    action: Action,
    boxes: list[OrientedBox],
    cfg: PlanConfig,
    inpainter: Inpainter | None = None,
) -> Scene:
    """One step of a plan on ``scene`` (left unchanged): the new version."""
    if action.type == "remove":
        rcfg = cfg.remove if not cfg.preview else dataclasses.replace(cfg.remove, inpaint=False)
        child, _ = remove(scene, boxes, rcfg, action.prompt, inpainter)
        return child
    specs = action.motions or []
    if len(specs) not in (1, len(boxes)):
        raise NeoError(
            f"{action.label}: {len(boxes)} objects but {len(specs)} motions (give one motion, "
            "or one per object)"
        )
    specs = specs * len(boxes) if len(specs) == 1 else specs
    motions = [Motion(b, s.matrix(b)) for b, s in zip(boxes, specs, strict=True)]
    mcfg = dataclasses.replace(cfg.move, preview=cfg.preview)
    return move(scene, motions, mcfg, action.prompt, inpainter)


def plan_boxes(action: Action) -> list[OrientedBox] | None:
    """The boxes an action gives itself (``box``), or None when it names a prompt."""
    if action.box is None:
        return None
    items = action.box if isinstance(action.box, list) else [action.box]
    try:
        return [OrientedBox.from_dict(b) for b in items]
    except (KeyError, TypeError, ValueError) as e:
        raise NeoError(f"{action.label}: malformed box: {e}") from None
