"""Action plans: a list of moves and removals applied one after another, each to the
version the previous step wrote (paper Sec. III-E: "NeRF it once, edit it many times").

A plan is YAML or JSON, a list of actions (or ``{actions: [...]}``)::

    - {type: move, prompt: red mug, translate_m: [0.10, 0.05, 0.0], yaw_deg: 45}
    - {type: remove, prompt: duck}
    - {type: move, prompt: lego brick, transform: [[1,0,0,0.1],[0,1,0,0],[0,0,1,0],[0,0,0,1]]}
    - {type: move, prompt: "red mug; duck", motions: [{translate_m: [0.1, 0, 0]},
                                                      {translate_m: [0, 0.1, 0], yaw_deg: 30}]}
    - {type: batch, edits: [{type: remove, prompt: duck},
                            {type: move, prompt: red mug, translate_m: [0.1, 0, 0]}]}

Each step queries the *current edited* version for its objects (``;`` separates several,
moved or removed in one edit), so a step sees where earlier steps put things. A move takes
one motion for all its objects, or ``motions`` with one per object; ``translate_m`` is in
world metres, ``yaw_deg`` turns about the vertical axis through the object's box centre,
``transform`` is a 4x4 world rigid motion (x' = T x). A step may give ``box`` (a box
mapping, or a list) instead of a prompt. A ``batch`` step applies its ``edits`` (moves and
removals in separate places) as one version (:class:`~neoedit.edit.batch.Batch`).
"""

from __future__ import annotations

import dataclasses
import difflib
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, ValidationError, model_validator

from neoedit.edit.batch import Batch, check_separate
from neoedit.edit.checks import check_edit_boxes
from neoedit.edit.inpaint import Inpainter
from neoedit.edit.motion import check_motions
from neoedit.edit.pipeline import Edit, apply_edit
from neoedit.edit.relocate import Motion, Move, MoveConfig, PreviewMove
from neoedit.edit.remove import Remove, RemoveConfig
from neoedit.errors import NeoError
from neoedit.geometry import OrientedBox, is_rigid, motion_about
from neoedit.language.relevancy import split_prompts
from neoedit.records import EditRecord
from neoedit.scene import Scene
from neoedit.utils.userfile import read_data_file
from neoedit.utils.validate import shorten


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
        if abs(self.yaw_deg) > 360.0:
            raise ValueError(f"yaw_deg is in degrees, within [-360, 360]; got {self.yaw_deg:g}")
        return self

    def matrix(self, box: OrientedBox) -> np.ndarray:
        if self.transform is not None:
            return np.asarray(self.transform, dtype=np.float64)
        t = np.asarray(self.translate_m or (0.0, 0.0, 0.0), dtype=np.float64)
        return motion_about(np.asarray(box.center_m), t, self.yaw_deg)


def _object_names(prompt: str | None) -> list[str]:
    """The objects a prompt names ('Red mug; duck' -> ['red mug', 'duck']), compared without
    case or extra spaces."""
    return [" ".join(p.casefold().split()) for p in split_prompts(prompt or "")]


class Action(BaseModel):
    model_config = ConfigDict(extra="forbid")
    type: Literal["move", "remove", "batch"]
    prompt: str | None = None
    box: dict[str, Any] | list[dict[str, Any]] | None = None
    translate_m: tuple[float, float, float] | None = None
    yaw_deg: float = 0.0
    transform: list[list[float]] | None = None
    motions: list[MotionSpec] | None = None
    edits: list[Action] | None = None
    """A batch's moves and removals (applied as one version)."""

    @model_validator(mode="after")
    def _consistent(self) -> Action:
        if self.type == "batch":
            return self._batch()
        if self.edits is not None:
            raise ValueError("only a batch step has edits")
        if (self.prompt is None) == (self.box is None):
            raise ValueError("give either prompt or box")
        if isinstance(self.box, list) and not self.box:
            raise ValueError("box is an empty list: give a box, or a list of boxes")
        if self.prompt is not None and not split_prompts(self.prompt):
            raise ValueError("the prompt is empty")
        names = _object_names(self.prompt)
        if len(set(names)) < len(names):
            twice = next(n for n in names if names.count(n) > 1)
            raise ValueError(f"the prompt names {shorten(twice)!r} twice")
        inline = self.translate_m is not None or self.yaw_deg != 0.0 or self.transform is not None
        if self.type == "remove":
            if inline or self.motions:
                raise ValueError("a remove takes no motion")
            return self
        if self.motions is not None and inline:
            raise ValueError("give either motions or one motion, not both")
        if self.motions is not None and not self.motions:
            raise ValueError("motions is empty: give one motion per object")
        objects = self.objects
        if self.motions is not None and len(self.motions) not in (1, objects):
            raise ValueError(
                f"{objects} object(s) but {len(self.motions)} motions: give one motion, or one "
                "per object"
            )
        if self.motions is None:
            self.motions = [
                MotionSpec(
                    translate_m=self.translate_m, yaw_deg=self.yaw_deg, transform=self.transform
                )
            ]
        return self

    def _batch(self) -> Action:
        own = [self.prompt, self.box, self.translate_m, self.transform, self.motions]
        if any(v is not None for v in own) or self.yaw_deg != 0.0:
            raise ValueError("a batch takes no prompt, box or motion of its own: its edits do")
        if not self.edits:
            raise ValueError("a batch lists its edits: edits: [{type: remove, ...}, ...]")
        if any(e.type == "batch" for e in self.edits):
            raise ValueError("a batch holds moves and removals, not batches")
        named: dict[str, int] = {}  # the edits of a batch must touch separate places
        for k, e in enumerate(self.edits, 1):
            for name in _object_names(e.prompt):
                if name in named:
                    raise ValueError(
                        f"edits {named[name]} and {k} both name {shorten(name)!r}: a batch "
                        "edits each object once (edit it again in a later step)"
                    )
                named[name] = k
        return self

    @property
    def steps(self) -> list[Action]:
        """The moves and removals of the step: a batch's edits, or the step itself."""
        return list(self.edits) if self.type == "batch" and self.edits else [self]

    @property
    def objects(self) -> int:
        """How many objects the step edits (one per prompt of ``a; b`` or per box)."""
        if self.type == "batch":
            return sum(e.objects for e in self.steps)
        if self.prompt is not None:
            return len(split_prompts(self.prompt))
        return len(self.box) if isinstance(self.box, list) else 1

    @property
    def label(self) -> str:
        if self.type == "batch":
            return f"batch ({', '.join(e.label for e in self.steps)})"
        return f"{self.type} {self.prompt!r}" if self.prompt else f"{self.type} box"


def _closest(key: str) -> str:
    """' (did you mean 'translate_m'?)' for a plan key like a known one ('' otherwise)."""
    known = list(dict.fromkeys([*Action.model_fields, *MotionSpec.model_fields]))
    close = difflib.get_close_matches(key, known, 1, 0.6)
    return f" (did you mean {close[0]!r}?)" if close else f" (known: {', '.join(known)})"


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
            path = list(err["loc"])
            if err["type"] == "missing" and path and isinstance(path[-1], int):
                path.pop()  # a short list: said of the list, not of its missing item
                err = {**err, "type": "too_short"}
            loc = ".".join(str(x) for x in path)
            msg = err["msg"].removeprefix("Value error, ")
            if err["type"] in ("too_short", "too_long") and path[-1:] == ["translate_m"]:
                msg = f"takes 3 numbers [x, y, z], got {_length(item, path)}"
            if err["type"] == "literal_error" and err["loc"][:1] == ("edits",):
                msg = "a batch's edits are of type 'move' or 'remove'"  # not 'batch'
            if err["type"] == "extra_forbidden":
                msg = f"unknown key{_closest(str(err['loc'][-1]))}"
            raise NeoError(f"{where}: step {i}: {loc + ': ' if loc else ''}{msg}") from None
    return actions


def _length(item: Any, path: list[Any]) -> str:
    """How many values the list at ``path`` of a plan step holds ('?' if it is not one)."""
    for key in path:
        try:
            item = item[key]
        except (KeyError, IndexError, TypeError):
            return "?"
    return str(len(item)) if isinstance(item, list) else "?"


def check_plan(scene: Scene, actions: list[Action]) -> None:
    """What can be checked against the starting scene before any step runs: boxes a step
    gives inside the scene box, and where they move to; translations that stay within its
    size; a batch's given boxes and targets apart. A failure names the step."""
    lo, hi = (np.asarray(v, dtype=np.float64) for v in scene.meta.aabb_m)
    reach = float(np.linalg.norm(hi - lo))
    for k, action in enumerate(actions, 1):
        try:
            regions = [_check_step(scene, step, reach) for step in action.steps]
            if action.type == "batch":
                check_separate([r for r in regions if r is not None])
        except NeoError as e:
            raise NeoError(f"step {k} ({action.label}): {e}") from None


def _check_step(scene: Scene, action: Action, reach: float) -> EditRecord | None:
    """Checks of one move or removal; the record of its given boxes and their targets (None
    for a prompt: its boxes are found when the step runs)."""
    for m in action.motions or []:
        shift = float(np.linalg.norm(m.translate_m or (0.0, 0.0, 0.0)))
        if m.transform is not None:
            shift = float(np.linalg.norm(np.asarray(m.transform)[:3, 3]))
        if shift > reach:
            raise NeoError(f"a move of {shift:.2f} m leaves the scene box ({reach:.2f} m across)")
    boxes = plan_boxes(action)
    if boxes is None:
        return None
    check_edit_boxes(scene, boxes)
    targets: list[OrientedBox] = []
    if action.type == "move":
        motions = _motions(action, boxes)
        check_motions(scene, motions)
        targets = [m.box.transformed(m.transform) for m in motions]
    given = {"boxes": [b.to_dict() for b in boxes], "target_boxes": [b.to_dict() for b in targets]}
    return EditRecord(action.type, details=given)


def load_plan(path: Path) -> list[Action]:
    path = Path(path)
    return parse_plan(read_data_file(path, "plan", yaml_ok=True), str(path))


@dataclass
class PlanConfig:
    preview: bool = False
    """Run every step as an instant preview (moves composed at render time, removals cut
    without inpainting): no training."""
    move: MoveConfig = field(default_factory=MoveConfig)
    remove: RemoveConfig = field(default_factory=RemoveConfig)


MoveEdit = Callable[[list[Motion], str | None], Edit]
"""Makes the edit of a move step from its motions and prompt (another method than NEO's)."""
FindBoxes = Callable[[Action], list[OrientedBox]]
"""The boxes of a move or removal's objects (its own ``box``, or its prompt's query)."""


def apply_action(
    scene: Scene,
    action: Action,
    find: FindBoxes,
    cfg: PlanConfig,
    inpainter: Inpainter | None = None,
    move_edit: MoveEdit | None = None,
) -> Scene:
    """One step of a plan on ``scene`` (left unchanged): the new version."""
    return apply_edit(scene, step_edit(action, find, cfg, inpainter, move_edit))


def step_edit(
    action: Action,
    find: FindBoxes,
    cfg: PlanConfig,
    inpainter: Inpainter | None = None,
    move_edit: MoveEdit | None = None,
) -> Edit:
    """The typed edit of one plan step, its objects' boxes from ``find``: a batch of its
    edits, or the step's own move or removal (:func:`action_edit`)."""
    if action.type == "batch":
        return Batch([action_edit(a, find(a), cfg, inpainter, move_edit) for a in action.steps])
    return action_edit(action, find(action), cfg, inpainter, move_edit)


def action_edit(
    action: Action,
    boxes: list[OrientedBox],
    cfg: PlanConfig,
    inpainter: Inpainter | None = None,
    move_edit: MoveEdit | None = None,
) -> Edit:
    """The typed edit of one move or removal of a plan on the objects in ``boxes``: NEO's,
    or for a move (not a preview) ``move_edit``'s when given."""
    if action.type == "batch":
        raise NeoError(f"{action.label}: a batch's edit is made by step_edit")
    if action.type == "remove":
        rcfg = cfg.remove if not cfg.preview else dataclasses.replace(cfg.remove, inpaint=False)
        # the language field follows a plan's removals as its moves (--edit.move.language)
        return Remove(boxes, rcfg, action.prompt, inpainter, language=cfg.move.language)
    motions = _motions(action, boxes)
    if cfg.preview:
        return PreviewMove(motions, cfg.move, action.prompt)
    if move_edit is not None:
        return move_edit(motions, action.prompt)
    return Move(motions, cfg.move, action.prompt, inpainter)


def _motions(action: Action, boxes: list[OrientedBox]) -> list[Motion]:
    """A move step's motion of each of its objects (one for all, or one per object)."""
    specs = action.motions or []
    if len(specs) not in (1, len(boxes)):
        raise NeoError(
            f"{action.label}: {len(boxes)} objects but {len(specs)} motions (give one motion, "
            "or one per object)"
        )
    specs = specs * len(boxes) if len(specs) == 1 else specs
    return [Motion(b, s.matrix(b)) for b, s in zip(boxes, specs, strict=True)]


def plan_boxes(action: Action) -> list[OrientedBox] | None:
    """The boxes an action gives itself (``box``), or None when it names a prompt."""
    if action.box is None:
        return None
    items = action.box if isinstance(action.box, list) else [action.box]
    try:
        return [OrientedBox.from_dict(b) for b in items]
    except (KeyError, TypeError, ValueError) as e:
        raise NeoError(f"{action.label}: malformed box: {e}") from None
