"""Edit it many times: scene stores (deltas, restore, lock, interrupted writes), plans,
chains of edits and batch moves."""

from __future__ import annotations

import contextlib
import io
import json
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
import torch
from hypothesis import given
from hypothesis import strategies as st
from test_move import FAST, SPARSE_ARGS, _fast_move_config, _mean_density

from neoedit.cameras.rays import CameraTensors
from neoedit.cli import main
from neoedit.edit.plan import parse_plan
from neoedit.edit.relocate import Motion, move
from neoedit.errors import NeoError
from neoedit.geometry import OrientedBox, motion_about
from neoedit.scene import load_scene, save_scene
from neoedit.storage import SceneStore
from neoedit.storage.blobs import decode, encode

PLAN_FAST = [a.replace("--edit.", "--edit.move.") for a in FAST] + [
    "--edit.remove.refine.steps", "30", "--edit.remove.refine.rounds", "1",
    "--edit.remove.views.turns", "1",
    # the default distillation: with half of it the fine move's student keeps a 1.5 cm
    # sliver of the mug at its old place (measured: 250 solid points of 390 left, 6 mm
    # centroid error; 23 points and 3 mm with the full schedule)
]  # fmt: skip


# -- blobs: sparse deltas ---------------------------------------------------------------------


@given(st.integers(0, 10_000), st.floats(1e-4, 10.0), st.integers(0, 2000))
def test_delta_encoding_round_trips_what_it_stores(seed, scale, n_changed):
    gen = torch.Generator().manual_seed(seed)
    parent = {"t": torch.randn(40, 100, generator=gen), "n": torch.tensor([3])}
    child = {k: v.clone() for k, v in parent.items()}
    idx = torch.randperm(4000, generator=gen)[:n_changed]
    child["t"].view(-1)[idx] += scale * torch.randn(n_changed, generator=gen)
    child["new"] = torch.randn(7, generator=gen)
    payload, entries, stored = encode(child, parent)
    assert entries["n"]["enc"] == "same" and entries["new"]["enc"] == "full"
    rebuilt = decode(payload, entries, parent, "test")
    for k in child:  # what loads is exactly what encode said it stored ...
        assert torch.equal(rebuilt[k], stored[k]), k
    # ... and that is the child up to half-precision rounding of each change
    err = (stored["t"] - child["t"]).abs()
    assert bool((err <= (child["t"] - parent["t"]).abs() / 1024 + 1e-6).all())
    if n_changed <= 800:  # a sparse change is stored as a delta, far smaller than in full
        assert entries["t"]["enc"] in ("delta", "same")
        assert sum(v.numel() * v.element_size() for v in payload.values()) < 4000 * 4 / 2


def test_a_point_cloud_after_an_edit_is_stored_as_kept_rows_plus_new_rows():
    gen = torch.Generator().manual_seed(0)
    parent = {"pts": torch.randn(1000, 3, generator=gen)}
    keep = torch.rand(1000, generator=gen) > 0.2
    child = {"pts": torch.cat([parent["pts"][keep], torch.randn(50, 3, generator=gen)])}
    payload, entries, stored = encode(child, parent)
    assert entries["pts"]["enc"] == "rows" and payload["new/pts"].shape == (50, 3)
    assert torch.equal(decode(payload, entries, parent, "test")["pts"], child["pts"])
    shuffled = {"pts": child["pts"].flip(0)}  # not kept rows in order: stored in full
    assert encode(shuffled, parent)[1]["pts"]["enc"] == "full"


# -- chains, plans, history ---------------------------------------------------------------------


def _tensors(scene) -> dict[str, torch.Tensor]:
    from neoedit.scene import _scene_groups

    return {f"{g}/{k}": v for g, d in _scene_groups(scene).items() for k, v in d.items()}


def _points_in(box: OrientedBox, n: int = 40000) -> torch.Tensor:
    gen = torch.Generator().manual_seed(0)
    u = (torch.rand(n, 3, generator=gen) - 0.5) * torch.tensor(box.size_m)
    pts = u @ torch.tensor(box.rotation, dtype=torch.float32).T + torch.tensor(box.center_m)
    return pts.float()


def _solid(scene, pts: torch.Tensor, sigma: float = 20.0) -> tuple[int, np.ndarray]:
    """How many of ``pts`` are solid (rendered density above ``sigma``: opaque within a few
    millimetres) and their centroid. Counted by volume, not density-weighted: a distilled
    student's peak densities differ from its teacher's (5000 vs 3500 at the 90th percentile)
    where both render the same opaque surface."""
    with torch.no_grad():
        solid = (scene.field.density(pts) * scene.grid.is_occupied(pts)) > sigma
    return int(solid.sum()), pts[solid].mean(0).numpy()


def _write_plan(path: Path, steps: list[dict]) -> Path:
    path.write_text(json.dumps(steps))
    return path


@pytest.fixture(scope="module")
def chain(move_scene: Path, tmp_path_factory) -> Path:
    """A plan of 3 edits on the tiny pick-and-place scene (a move, a fine move of 1.5 cm
    and 4 degrees whose boxes overlap, a removal), then a step whose prompt matches nothing."""
    root = tmp_path_factory.mktemp("chain")
    plan = _write_plan(
        root / "plan.json",
        [
            {"type": "move", "prompt": "red mug", "translate_m": [0.08, 0.04, 0.0], "yaw_deg": 30},
            {"type": "move", "prompt": "red mug", "translate_m": [0.015, 0.0, 0.0], "yaw_deg": 4},
            {"type": "remove", "prompt": "red mug"},
            {"type": "move", "prompt": "purple elephant", "translate_m": [0.1, 0.0, 0.0]},
        ],
    )
    args = ["plan", str(move_scene), str(plan), "--out", str(root / "store"), "--no-report"]
    err = io.StringIO()
    with contextlib.redirect_stderr(err):
        assert main([*args, *PLAN_FAST, *SPARSE_ARGS]) == 1  # its prompt matches nothing
    (root / "stderr.txt").write_text(err.getvalue())
    return root / "store"


def test_plan_writes_a_chain_every_verb_accepts(chain: Path, move_scene: Path, capsys):
    store = SceneStore(chain)
    assert store.names() == ["step_0", "step_1", "step_2", "step_3"]  # kept before the stop
    assert store.current == "step_3" and (chain / "plan.png").is_file()
    assert not any((chain / f"step_{k}" / "report").exists() for k in (1, 2, 3))  # --no-report
    message = " ".join((chain.parent / "stderr.txt").read_text().split())
    assert "step 4 (move 'purple elephant')" in message and "the plan stopped" in message
    first, fine = load_scene(chain / "step_1"), load_scene(chain / "step_2")
    # the fine move: boxes overlap, the mug is whole at its new place, not doubled
    src = OrientedBox.from_dict(fine.meta.edits[-1].details["source_boxes"][0])
    tgt = OrientedBox.from_dict(fine.meta.edits[-1].details["target_boxes"][0])
    assert OrientedBox.from_dict(fine.meta.edits[-1].details["boxes"][0]).center_m[0] > 0.1
    around = _points_in(src.grown(0.03))  # holds both boxes ...
    # ... and the table top: only what stands 1 cm above the box's floor is the mug
    around = around[around[:, 2] > src.center_m[2] - src.size_m[2] / 2 + 0.01]
    (v0, c0), (v1, c1) = _solid(first, around), _solid(fine, around)
    assert 0.75 < v1 / v0 < 1.33  # neither cut away nor doubled ...
    shift = (np.asarray(tgt.center_m) - np.asarray(src.center_m))[:2]
    moved = (c1 - c0)[:2]
    along = float(moved @ shift / np.linalg.norm(shift))
    across = float(np.linalg.norm(moved - along * shift / np.linalg.norm(shift)))
    # ... and moved by the 1.5 cm of the motion, not left in place. The solid points'
    # centroid also drifts sideways on this tiny field: 6.9 mm in a fresh environment of
    # 2026-12-05 under pytest-xdist (under 5 mm before; 1.4 mm along), cause not found
    assert abs(along - np.linalg.norm(shift)) < 0.004, (along, shift)
    assert across < 0.01, across
    removed = load_scene(chain)  # the store: its current version
    assert _mean_density(removed, tgt) < 0.25 * _mean_density(fine, tgt)
    # each step's base field is the original's, stored once: every edit is a patch
    for name in ("step_1", "step_2", "step_3"):
        entries = store.info(name).manifest["groups"]["field"]["tensors"]
        assert entries["field.encoding.table"]["enc"] == "same"
    # bounded storage: the chain costs less than two full copies of the scene beyond step_0
    full = store.info("step_0").manifest["bytes"]
    assert sum(store.info(n).manifest["bytes"] for n in store.names()) < 3 * full
    # every verb takes a store version (and the store) as a scene
    r = chain.parent / "render"
    assert main(["render", str(chain / "step_2"), "--views", "eval", "--out", str(r)]) == 0
    assert main(["query", str(chain / "step_1"), "red mug", "--views", "0", *SPARSE_ARGS]) == 0
    assert main(["log", str(chain)]) == 0
    assert "step_3 *" in capsys.readouterr().out


def test_restore_is_bit_identical_and_keeps_later_versions(chain: Path, sim_root: Path):
    store = SceneStore(chain)
    before = _tensors(load_scene(chain / "step_1"))
    # another edit into the store (from a store version), then undo to step_1
    box = json.dumps(load_scene(chain / "step_1").meta.edits[-1].details["target_boxes"][0])
    (chain.parent / "box.json").write_text(box)
    args = ["move", str(chain / "step_1"), "--box", str(chain.parent / "box.json")]
    assert (
        main([*args, "--translate", "0", "0.05", "0", "--preview", "--out", str(chain / "alt")])
        == 0
    )
    assert store.current == "alt" and load_scene(chain).meta.moves
    assert main(["restore", str(chain), "step_1"]) == 0
    after = _tensors(load_scene(chain))
    assert before.keys() == after.keys()
    assert all(torch.equal(before[k], after[k]) for k in before)
    assert {"alt", "step_3"} <= set(store.names())  # nothing lost
    assert main(["restore", str(chain), "alt"]) == 0 and store.current == "alt"
    # a store version is never replaced, even with --overwrite
    assert (
        main(
            [
                *args,
                "--translate",
                "0",
                "0.05",
                "0",
                "--preview",
                "--out",
                str(chain / "alt"),
                "--overwrite",
            ]
        )
        == 2
    )
    diff = chain.parent / "diff"
    assert main(["diff", str(chain), "step_0", "step_1", "--out", str(diff)]) == 0
    assert (diff / "diff.png").is_file()
    psnr = json.loads((diff / "diff.json").read_text())["views"][0]["psnr_a_vs_b"]
    assert 10 < psnr < 60  # the two versions differ where the mug moved, and only there


def test_versions_keep_their_write_order_when_the_store_is_copied(tmp_path: Path):
    import os
    import shutil

    store = SceneStore.create(tmp_path / "store")
    parent = None
    for k, name in enumerate(["zeta", "alpha", "mid"]):  # not alphabetical
        groups = {"field": {"w": torch.full((4,), float(k))}}
        store.write(name, groups, {"version_id": name * 2, "parent": parent})
        parent = name * 2
    assert store.names() == ["zeta", "alpha", "mid"]
    copy = tmp_path / "copy"  # cp -r: every file gets a new time, here in reverse order
    shutil.copytree(store.root, copy, copy_function=shutil.copy)
    for t, name in enumerate(["mid", "alpha", "zeta"]):
        os.utime(copy / name, ns=(10**18 + t, 10**18 + t))
    moved = SceneStore(copy)
    assert moved.names() == ["zeta", "alpha", "mid"]
    assert float(moved.tensors("mid")["field"]["w"][0]) == 2.0


def test_a_killed_write_leaves_the_store_valid(chain: Path, tmp_path: Path):
    import shutil

    copy = tmp_path / "store"
    shutil.copytree(chain, copy)
    store = SceneStore(copy)
    names, current = store.names(), store.current
    scene = load_scene(copy / "step_1")
    scene.meta.parent, scene.meta.version_id = scene.meta.version_id, "feedfeedfeed"

    def crash(_folder: Path) -> None:
        raise RuntimeError("killed while writing")

    with pytest.raises(RuntimeError):
        save_scene(copy / "step_9", scene, extras=crash)
    assert store.names() == names and store.current == current
    assert not (copy / "step_9").exists()
    for n in names:  # every earlier version still loads
        load_scene(copy / n)
    # what a writer killed by the OS leaves (its temporary folder) is no version
    partial = copy / ".step_9.neoedit-999999-0badc0de.partial"
    shutil.copytree(copy / "step_1", partial)
    assert store.names() == names
    with pytest.raises(NeoError):
        store.set_current(partial.name)
    # ... nor are the blobs it wrote before it died: the next write removes both
    orphan = copy / "blobs" / f"{'ab' * 32}.st.z"
    orphan.write_bytes(b"written by a killed writer")
    blob_tmp = copy / "blobs" / f".{'cd' * 32}.st.z.neoedit-999999-0badc0de.tmp"
    blob_tmp.write_bytes(b"half a blob")
    kept = sorted(p.name for p in (copy / "blobs").iterdir() if p not in (orphan, blob_tmp))
    save_scene(copy / "step_9", scene)
    assert not partial.exists() and not orphan.exists() and not blob_tmp.exists()
    assert set(kept) <= {p.name for p in (copy / "blobs").iterdir()}  # every version's blobs
    for n in [*names, "step_9"]:
        load_scene(copy / n)


def test_log_and_diff_read_any_record(chain: Path, tmp_path: Path, capsys):
    """A record a user edited (a missing field) still lists; diffing a version with itself
    says 'identical' and writes valid JSON (no Infinity)."""
    import shutil

    copy = tmp_path / "store"
    shutil.copytree(chain, copy)
    meta = json.loads((copy / "step_1" / "scene.json").read_text())
    for key in ("type", "seconds", "transforms"):
        meta["edits"][-1].pop(key, None)
    (copy / "step_1" / "scene.json").write_text(json.dumps(meta))
    capsys.readouterr()
    assert main(["log", str(copy)]) == 0
    out = capsys.readouterr().out
    assert "step_1" in out and "step_3" in out, out
    out_dir = tmp_path / "diff"
    assert main(["diff", str(copy), "step_2", "step_2", "--out", str(out_dir), "--views", "1"]) == 0
    assert "identical" in capsys.readouterr().out

    def refuse(value: str) -> None:
        raise ValueError(f"not JSON: {value}")

    report = json.loads((out_dir / "diff.json").read_text(), parse_constant=refuse)
    assert report["views"][0]["identical"] and report["views"][0]["psnr_a_vs_b"] is None


def test_a_second_writer_gets_a_clear_lock_error(chain: Path, capsys):
    holder = textwrap.dedent(
        f"""
        import sys, time
        from neoedit.storage import SceneStore
        with SceneStore({str(chain)!r}).lock():
            print("locked", flush=True)
            sys.stdin.readline()
        """
    )
    proc = subprocess.Popen(
        [sys.executable, "-c", holder], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True
    )
    try:
        assert proc.stdout is not None and proc.stdout.readline().strip() == "locked"
        assert main(["restore", str(chain), "step_0"]) == 2
        err = " ".join(capsys.readouterr().err.split())
        assert "is being written by another neo process (pid" in err
    finally:
        proc.communicate("\n", timeout=30)
    assert main(["restore", str(chain), "step_0"]) == 0  # free again


@pytest.mark.parametrize(
    ("steps", "message"),
    [
        ([{"type": "rotate", "prompt": "mug"}], "type"),
        ([{"type": "move", "prompt": "mug"}], "needs a motion"),
        (
            [{"type": "move", "prompt": "mug", "transform": np.diag([2, 2, 2, 1]).tolist()}],
            "rigid",
        ),
        ([{"type": "remove", "prompt": "mug", "yaw_deg": 3}], "takes no motion"),
        ([{"type": "remove"}], "either prompt or box"),
        ([], "non-empty list"),
    ],
)
def test_plan_errors_are_clear(steps, message, tmp_path: Path, capsys):
    with pytest.raises(NeoError, match=message):
        parse_plan(steps)
    plan = _write_plan(tmp_path / "plan.json", steps)
    assert main(["plan", str(tmp_path / "no_scene"), str(plan), "--out", str(tmp_path / "o")]) == 2
    assert message in " ".join(capsys.readouterr().err.split()) and not (tmp_path / "o").exists()


def test_a_plan_runs_its_moves_by_the_method_asked_for():
    """``neo plan --method seal3d``: each move step is the baseline's edit with the
    command's settings; removals and previews stay NEO's."""
    from neoedit.bench.seal3d import Seal3dConfig, SealMove
    from neoedit.edit.plan import PlanConfig, action_edit
    from neoedit.edit.relocate import Move, PreviewMove
    from neoedit.edit.remove import Remove

    box = OrientedBox((0.0, 0.0, 0.05), (0.1, 0.1, 0.1), 0.0)
    move_step, remove_step = parse_plan(
        [{"type": "move", "box": box.to_dict(), "translate_m": [0.1, 0, 0]},
         {"type": "remove", "box": box.to_dict()}]
    )  # fmt: skip
    seal = Seal3dConfig(margin_m=0.02)
    edit = action_edit(move_step, [box], PlanConfig(), move_edit=seal.move_edit())
    assert isinstance(edit, SealMove) and edit.cfg is seal
    assert np.allclose(edit.motions[0].transform[:3, 3], [0.1, 0, 0])
    assert isinstance(action_edit(move_step, [box], PlanConfig()), Move)
    preview = action_edit(move_step, [box], PlanConfig(preview=True), move_edit=seal.move_edit())
    assert isinstance(preview, PreviewMove)
    assert isinstance(
        action_edit(remove_step, [box], PlanConfig(), move_edit=seal.move_edit()), Remove
    )


def test_batch_move_of_two_objects_moves_both(move_scene: Path, sim_root: Path):
    objects = json.loads((sim_root / "pick_place_1" / "pre" / "objects.json").read_text())
    boxes = [OrientedBox.from_dict(o["box"]) for o in objects["objects"]]
    assert len(boxes) == 2
    parent = load_scene(move_scene)
    shift = [np.array([0.0, 0.12, 0.0]), np.array([0.1, 0.0, 0.0])]
    motions = [
        Motion(b, motion_about(np.array(b.center_m), s, 0.0))
        for b, s in zip(boxes, shift, strict=True)
    ]
    child = move(parent, motions, _fast_move_config(), "red mug; soccer ball")
    rec = child.meta.edits[-1]
    # one patch for both holes, and each object carried under its motion
    assert len(rec.details["source_boxes"]) == 2 and len(child.field.patches) == 3
    assert [t is None for t in child.field.part_transforms()] == [True, False, False]
    for src, tgt in zip(rec.details["source_boxes"], rec.details["target_boxes"], strict=True):
        s, t = OrientedBox.from_dict(src), OrientedBox.from_dict(tgt)
        assert _mean_density(child, s) < 0.5 * _mean_density(parent, s)
        assert _mean_density(child, t) > 2 * _mean_density(parent, t)
    cams = CameraTensors(child.scan_cameras()[0])
    assert child.render_image(cams, 0, 48, 64)["rgb"].isfinite().all()


def test_a_preview_plan_trains_nothing_and_each_step_sees_the_last(
    move_scene: Path, tmp_path: Path
):
    plan = _write_plan(
        tmp_path / "plan.json",
        [
            {"type": "move", "prompt": "red mug", "translate_m": [0.08, 0.04, 0.0], "yaw_deg": 30},
            {"type": "remove", "prompt": "red mug"},
        ],
    )
    out = tmp_path / "store"
    assert (
        main(
            ["plan", str(move_scene), str(plan), "--out", str(out), "--preview", *SPARSE_ARGS]
            + ["--edit.move.language.steps", "40"]
            + ["--json", str(tmp_path / "plan_result.json")]
        )
        == 0
    )
    moved, removed = load_scene(out / "step_1"), load_scene(out / "step_2")
    result = json.loads((tmp_path / "plan_result.json").read_text())
    assert [s["step"] for s in result["steps"]] == [1, 2]
    assert [s["version_id"] for s in result["steps"]] == [
        moved.meta.version_id,
        removed.meta.version_id,
    ]
    assert result["steps"][1]["parent"] == moved.meta.version_id
    assert moved.meta.moves and moved.meta.edits[-1].method == "preview"
    # step 2 queried the preview: the mug was found where step 1 put it
    target = OrientedBox.from_dict(moved.meta.moves[0]["target"])
    found = OrientedBox.from_dict(removed.meta.edits[-1].details["boxes"][0])
    assert np.linalg.norm(np.subtract(found.center_m, target.center_m)[:2]) < 0.03
    assert removed.meta.cut_boxes and removed.meta.moves  # both render-time, nothing trained
    assert all((out / f"step_{k}" / "report" / "before_after.png").is_file() for k in (1, 2))
    assert result["steps"][0]["report"] == str(out / "step_1" / "report")
    for name in ("step_1", "step_2"):  # a preview stores no new field content
        entries = SceneStore(out).info(name).manifest["groups"]["field"]["tensors"]
        assert all(e["enc"] != "full" for k, e in entries.items() if k.startswith("field."))


def test_a_whole_field_student_on_a_patched_version_saves_and_loads(chain: Path, tmp_path: Path):
    """A move whose student is the whole field bakes the parent's patches in: the saved
    version lists none (a stale list made it unloadable)."""
    parent = load_scene(chain / "step_1")  # a patched version
    assert isinstance(parent.field.patches, torch.nn.ModuleList) and len(parent.field.patches)
    box = OrientedBox.from_dict(parent.meta.edits[-1].details["target_boxes"][0])
    child = move(
        parent,
        [Motion(box, motion_about(np.array(box.center_m), np.array([0.0, 0.06, 0.0]), 0.0))],
        _fast_move_config(student="field"),
    )
    save_scene(tmp_path / "v", child)
    again = load_scene(tmp_path / "v")
    assert not again.meta.patches and not hasattr(again.field, "patches")
