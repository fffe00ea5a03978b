"""Several edits as one version (issue 41): a batch removes one object and moves another in
one new version with one history entry; overlapping or mixed batches are refused before any
work; a saved batch loads back with its parts."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest
import torch
from test_move import _mean_density

from neoedit.edit import (
    Batch,
    Move,
    MoveConfig,
    PreviewMove,
    Remove,
    RemoveConfig,
    apply_edit,
    sketch,
)
from neoedit.edit.motion import Motion
from neoedit.errors import NeoError
from neoedit.geometry import OrientedBox, motion_about
from neoedit.scene import Scene, load_scene, save_scene

SHIFT = np.array([0.0, 0.12, 0.0])
"""The mug's motion: 12 cm along +y, onto free table, away from the ball."""


@pytest.fixture(scope="module")
def objects(sim_root: Path) -> dict[str, OrientedBox]:
    raw = json.loads((sim_root / "pick_place_1" / "pre" / "objects.json").read_text())
    return {o["name"]: OrientedBox.from_dict(o["box"]) for o in raw["objects"]}


def _fast_remove() -> RemoveConfig:
    cfg = RemoveConfig()
    cfg.refine.steps, cfg.refine.rounds, cfg.views.turns = 30, 1, 1
    return cfg


def _fast_move() -> MoveConfig:
    cfg = MoveConfig(remove=_fast_remove())
    cfg.language.steps = 60
    return cfg


def _mug_motion(objects: dict[str, OrientedBox]) -> Motion:
    mug = objects["red mug"]
    return Motion(mug, motion_about(np.array(mug.center_m), SHIFT, 0.0))


def _moved(box: OrientedBox) -> OrientedBox:
    return dataclasses.replace(box, center_m=tuple(np.add(box.center_m, SHIFT)))


def _renderable_density(scene: Scene, box: OrientedBox) -> float:
    """Share of opaque points in the box's inner part, as the version renders (render-time
    cuts and moves applied)."""
    field, _ = scene.renderable()
    inner = np.random.default_rng(0).uniform(-0.4, 0.4, (4000, 3)) * np.asarray(box.size_m)
    pts = inner @ box.rotation.T + np.asarray(box.center_m)
    with torch.no_grad():
        sigma = field.density(torch.as_tensor(pts, dtype=torch.float32))
    return float((sigma > 100.0).float().mean())


def test_an_instant_batch_cuts_one_object_and_previews_another_in_one_version(
    move_scene: Path, objects
):
    parent = load_scene(move_scene)
    ball, mug = objects["soccer ball"], objects["red mug"]
    before = (parent.meta.version_id, len(parent.meta.edits))
    batch = Batch(
        [
            Remove([ball], dataclasses.replace(RemoveConfig(), inpaint=False), "soccer ball"),
            PreviewMove([_mug_motion(objects)], prompt="red mug"),
        ]
    )
    child = apply_edit(parent, batch)
    assert (parent.meta.version_id, len(parent.meta.edits)) == before  # parent unchanged
    assert len(child.meta.edits) == before[1] + 1  # one entry for both edits
    rec = child.meta.edits[-1]
    assert rec.type == "batch" and rec.prompt == "soccer ball; red mug"
    assert rec.label == "batch (remove (cut), move (preview))"
    assert [p.type for p in rec.parts()] == ["remove", "move"]
    assert "edit2_preview_s" in rec.timings and "preview_s" not in rec.timings  # per edit
    assert child.meta.cut_boxes and child.meta.moves
    # the ball is cut out of every ray (a render-time cut: its box is recorded), the mug is
    # composed at its target (measured: opaque share 0.47 -> 0.02 at the source, 0.00 ->
    # 0.43 in the target box)
    assert any(
        OrientedBox.from_dict(b).contains(np.array([ball.center_m]))[0]
        for b in child.meta.cut_boxes
    )
    assert _renderable_density(child, mug) < 0.25 * _renderable_density(parent, mug)
    target = _moved(mug)
    assert _renderable_density(child, target) > _renderable_density(parent, target) + 0.2
    # the batch's boxes are its edits' (what the report outlines)
    assert len(rec.boxes("boxes")) == 2
    # instant as a whole: the viewer can sketch it
    light = sketch(parent, batch)
    assert light.meta.cut_boxes == child.meta.cut_boxes and len(light.meta.moves) == 1


def test_a_trained_batch_removes_one_object_and_moves_another(
    move_scene: Path, objects, tmp_path: Path
):
    parent = load_scene(move_scene)
    ball, mug = objects["soccer ball"], objects["red mug"]
    batch = Batch(
        [
            Remove([ball], _fast_remove(), "soccer ball"),
            Move([_mug_motion(objects)], _fast_move(), "red mug"),
        ]
    )
    child = apply_edit(parent, batch)
    rec = child.meta.edits[-1]
    assert _mean_density(child, ball) < 0.3 * _mean_density(parent, ball)
    assert _mean_density(child, mug) < 0.5 * _mean_density(parent, mug)
    target = _moved(mug)
    assert _mean_density(child, target) > 2 * _mean_density(parent, target)
    # the move ran on the removal's result, not on the parent: the removal's patch is kept
    # beside the move's two (the hole's and the carried mug)
    assert len(child.field.patches) == 3
    assert "edit1_grid_s" in rec.timings and "language_total_s" in rec.timings
    # the language field was updated once, for both regions, and saved with the version
    assert child.language is not parent.language
    save_scene(tmp_path / "v", child)
    loaded = load_scene(tmp_path / "v")
    assert len(loaded.field.patches) == len(loaded.meta.patches) == 3
    again = loaded.meta.edits[-1]
    assert again.label == rec.label == "batch (remove, move (neo))"
    assert again.parts()[1].details["target_boxes"] == rec.parts()[1].details["target_boxes"]


def test_batches_that_cannot_run_are_refused_before_any_work(move_scene: Path, objects):
    parent = load_scene(move_scene)
    mug, ball = objects["red mug"], objects["soccer ball"]
    cut = dataclasses.replace(RemoveConfig(), inpaint=False)
    cases = [
        (Batch([]), "at least one edit"),
        (Batch([Remove([mug], cut), PreviewMove([_mug_motion(objects)])]), "same place"),
        (Batch([Remove([ball], cut), Move([_mug_motion(objects)], _fast_move())]), "all train or are all instant"),
        (Batch([Batch([Remove([ball], cut)])]), "not batches"),
    ]  # fmt: skip
    for batch, message in cases:
        with pytest.raises(NeoError, match=message):
            batch.prepare(parent)


def test_a_batch_step_of_a_plan_is_one_version(move_scene: Path, objects, tmp_path: Path, capsys):
    """`neo plan` with a batch step (previews: nothing trains): one version with both
    edits; `neo log` names it. (Boxes, not prompts: the tiny scene's language field finds
    the mug for "soccer ball", and the batch refuses two edits of one object.)"""
    from neoedit.cli import main

    steps = [
        {
            "type": "batch",
            "edits": [
                {"type": "remove", "box": objects["soccer ball"].to_dict()},
                {
                    "type": "move",
                    "box": objects["red mug"].to_dict(),
                    "translate_m": SHIFT.tolist(),
                },
            ],
        }
    ]
    (tmp_path / "plan.json").write_text(json.dumps(steps))
    out = tmp_path / "store"
    argv = ["plan", str(move_scene), str(tmp_path / "plan.json"), "--out", str(out)]
    assert main([*argv, "--preview", "--no-report"]) == 0
    step = load_scene(out / "step_1")
    rec = step.meta.edits[-1]
    assert rec.label == "batch (remove (cut), move (preview))" and rec.prompt is None
    assert step.meta.cut_boxes and step.meta.moves and step.meta.parent is not None
    capsys.readouterr()
    assert main(["log", str(out)]) == 0
    log = " ".join(capsys.readouterr().out.split())
    assert "batch" in log and "+0.000, +0.120, +0.000" in log  # the move's motion shown


@pytest.mark.parametrize(
    ("step", "message"),
    [
        ({"type": "batch"}, "lists its edits"),
        ({"type": "batch", "edits": []}, "lists its edits"),
        ({"type": "batch", "prompt": "mug", "edits": [{"type": "remove", "prompt": "a"}]}, "no prompt"),
        ({"type": "batch", "edits": [{"type": "batch", "edits": [{"type": "remove", "prompt": "a"}]}]}, "not batches"),
        ({"type": "remove", "prompt": "a", "edits": [{"type": "remove", "prompt": "b"}]}, "only a batch"),
        ({"type": "batch", "edits": [{"type": "move", "prompt": "a"}]}, "step 1: edits.0: .*needs a motion"),
        ({"type": "batch", "edits": [{"type": "grasp", "prompt": "a"}]}, "edits.0.type: .*'move' or 'remove'$"),
        ({"type": "move", "prompt": "a", "translate": [0.1, 0, 0]}, "translate: unknown key \\(did you mean 'translate_m'"),
        # one object twice in a batch: refused when the plan is read, not after step 1 ran
        ({"type": "batch", "edits": [{"type": "move", "prompt": "mug", "translate_m": [0.01, 0, 0]}, {"type": "move", "prompt": " Mug", "translate_m": [0.02, 0, 0]}]}, "step 1: edits 1 and 2 both name 'mug'"),
        ({"type": "batch", "edits": [{"type": "remove", "prompt": "duck; mug"}, {"type": "move", "prompt": "mug", "translate_m": [0.02, 0, 0]}]}, "edits 1 and 2 both name 'mug'"),
        ({"type": "move", "prompt": "mug; MUG", "translate_m": [0.02, 0, 0]}, "step 1: the prompt names 'mug' twice"),
    ],
)  # fmt: skip
def test_a_malformed_batch_step_is_refused_with_its_step(step: dict, message: str):
    from neoedit.edit.plan import parse_plan

    with pytest.raises(NeoError, match=message):
        parse_plan([step])


def test_a_batch_step_is_labelled_by_its_edits():
    from neoedit.edit.plan import parse_plan

    (step,) = parse_plan([{"type": "batch", "edits": [{"type": "remove", "prompt": "duck"}, {"type": "remove", "box": {"center": [0, 0, 0], "size": [0.1, 0.1, 0.1]}}]}])  # fmt: skip
    assert step.label == "batch (remove 'duck', remove box)" and step.objects == 2
    assert [s.type for s in step.steps] == ["remove", "remove"]


def test_a_stored_batch_record_reads_back_even_when_malformed():
    from neoedit.records import EditRecord

    box = {"center": [0.0, 0.0, 0.05], "size": [0.1, 0.1, 0.1], "yaw_deg": 0.0}
    raw = {"type": "batch", "edits": [{"type": "remove", "inpaint": "fsr", "boxes": [box]}, 7]}
    rec = EditRecord.parse(raw)
    assert [p.type for p in rec.parts()] == ["remove", "?"] and rec.label == "batch (remove, ?)"
    assert len(rec.boxes()) == 1 and EditRecord.parse(rec.to_dict()).to_dict() == rec.to_dict()
    assert EditRecord.parse({"type": "batch", "edits": "x"}).label == "batch"


def test_the_demo_plan_reads_with_its_batch_step():
    from neoedit.edit.plan import load_plan

    root = Path(__file__).resolve().parents[1]
    labels = [a.label for a in load_plan(root / "examples" / "demo_plan.yaml")]
    assert labels == ["move 'duck'", "batch (move 'mug', remove 'soccer ball')", "remove 'duck'"]


def test_a_plan_whose_first_step_fails_leaves_nothing(move_scene: Path, tmp_path: Path, capsys):
    """The store would hold only a copy of the input: the plan removes what it made (a rerun
    to the same --out works); a later step's failure keeps the versions before it."""
    from test_move import SPARSE_ARGS

    from neoedit.cli import main

    steps = [{"type": "move", "prompt": "purple elephant", "translate_m": [0.05, 0.0, 0.0]}]
    (tmp_path / "plan.json").write_text(json.dumps(steps))
    out = tmp_path / "store"
    argv = ["plan", str(move_scene), str(tmp_path / "plan.json"), "--out", str(out), "--preview"]
    assert main([*argv, *SPARSE_ARGS]) == 1  # nothing found: the status of neo query
    err = " ".join(capsys.readouterr().err.split())
    assert "step 1 (move 'purple elephant')" in err and "nothing was written" in err
    assert not out.exists()
