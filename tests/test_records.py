"""The edit history's records: typed in memory, flat JSON on disk, tolerant of hand edits."""

from __future__ import annotations

import json

from pydantic import TypeAdapter

from neoedit.geometry import OrientedBox
from neoedit.records import EditRecord, own_edit
from neoedit.scene import SceneMeta

BOX = OrientedBox((0.1, 0.0, 0.05), (0.08, 0.08, 0.1), 30.0).to_dict()
STORED = {  # a move record as every version since the first format stores it
    "type": "move",
    "prompt": "red mug",
    "method": "neo",
    "boxes": [BOX],
    "target_boxes": [BOX, {"center": "not a box"}, 7],
    "transforms": [[[1, 0, 0, 0.1], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]],
    "config": {"carry": True},
    "parent": "aaaaaaaaaaaa",
    "version": "bbbbbbbbbbbb",
    "seconds": 12.5,
    "timings": {"distill_s": 8.0, "loss_render": 0.01},
}


def test_a_stored_record_is_typed_and_written_back_unchanged():
    rec = EditRecord.parse(STORED)
    assert (rec.type, rec.prompt, rec.method, rec.seconds) == ("move", "red mug", "neo", 12.5)
    assert (rec.parent, rec.version, rec.timings["distill_s"]) == (
        "aaaaaaaaaaaa",
        "bbbbbbbbbbbb",
        8.0,
    )
    assert rec.details["config"] == {"carry": True} and "type" not in rec.details
    assert rec.to_dict() == STORED
    assert rec.label == "move (neo)"
    # boxes by kind, the malformed entry skipped
    assert [b.to_dict() for b in rec.boxes("target_boxes")] == [BOX]
    assert len(rec.boxes()) == 2


def test_scene_meta_keeps_records_typed_and_stores_them_flat():
    meta = SceneMeta(data_path="d", aabb_m=[[-1, -1, 0], [1, 1, 1]], background_rgb=[1, 1, 1])
    meta.edits.append(EditRecord.parse(STORED))
    raw = json.loads(json.dumps(meta.to_dict()))
    assert raw["edits"] == [STORED]  # no nested "details": old readers read it as before
    again = TypeAdapter(SceneMeta).validate_python(raw)
    assert isinstance(again.edits[0], EditRecord) and again.edits[0] == meta.edits[0]


def test_hand_edited_or_partial_records_never_raise():
    assert EditRecord.parse("garbage").type == "?"
    rec = EditRecord.parse({"type": 3, "seconds": "slow", "timings": [1], "prompt": None})
    assert (rec.type, rec.seconds, rec.timings, rec.prompt) == ("?", None, {}, None)
    odd = {**STORED, "timings": {"distill_s": "slow", "loss_render": 0.5}, "seconds": True}
    raw = {"data_path": "d", "aabb_m": [[0, 0, 0], [1, 1, 1]], "background_rgb": [1, 1, 1]}
    meta = TypeAdapter(SceneMeta).validate_python({**raw, "edits": [odd, "garbage"]})
    assert meta.edits[0].timings == {"loss_render": 0.5} and meta.edits[0].seconds is None
    assert meta.edits[1].type == "?"  # the scene still loads
    cut = EditRecord.parse({"type": "remove", "removal": "resample", "inpaint": None})
    assert cut.label == "remove (cut)"
    # neo remove --removal suppress --no-inpaint: recorded as the DFF-style method (a record
    # written before that, with no method, is labelled by its details)
    for method in ("suppress", None):
        raw = {"type": "remove", "method": method, "removal": "suppress", "inpaint": None}
        assert EditRecord.parse(raw).label == "remove (suppress)"
    assert EditRecord.parse({"type": "remove", "inpaint": "fsr"}).label == "remove"
    assert EditRecord.parse({"type": "remove", "method": "seal3d"}).label == "remove (seal3d)"


def test_own_edit_is_the_record_of_the_version_itself():
    assert own_edit({"edits": [STORED], "version_id": "bbbbbbbbbbbb"}).method == "neo"
    assert own_edit({"edits": [STORED], "version_id": "cccccccccccc"}) is None  # an ancestor's
    assert own_edit({"edits": [], "version_id": "x"}) is None  # a trained scan
    assert own_edit({"edits": "broken"}) is None and own_edit(None) is None


def test_a_stage_entered_many_times_sums_its_unrounded_seconds(monkeypatch):
    """Each entry of a stage adds its exact time (a thousand 4 ms steps are 4 s, not 0);
    the record shows the total rounded to 10 ms."""
    from neoedit.utils import timings as timings_module

    clock = iter(x * 0.004 for x in range(2000))  # every call 4 ms after the one before
    monkeypatch.setattr(timings_module.time, "perf_counter", lambda: next(clock))
    timings = timings_module.Timings()
    for _ in range(1000):
        with timings.stage("train"):
            pass
    assert timings["train_s"] == 4.0 and abs(timings.seconds("train") - 4.0) < 1e-9
    timings["train_s"] = 1.5  # set by hand: only the value given is known
    assert timings.seconds("train") == 1.5
