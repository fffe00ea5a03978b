"""Bad input, as a hostile but realistic user gives it (issue 12): every case ends in one
clear message and exit status 2 (or succeeds), never a traceback, and a refused command
leaves the workspace byte-identical with no temporary left behind.

One case per line: ``C(id, argv, status, message fragment, setup)``. ``argv`` is split like a
shell line; ``{data}``, ``{scene}`` and ``{ws}`` are a fresh copy of the tiny dataset, the
tiny scene and the folder holding both (also the working directory).
"""

# ruff: noqa: F811 (the golden fixture is imported and used as an argument)
from __future__ import annotations

import contextlib
import io
import shlex
import shutil
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from neoedit.utils.io import mark_output
from tests.safety_support import (
    TINY_TRAIN_ARGS,
    Setup,
    Workspace,
    chain,
    changes,
    golden,  # noqa: F401 (a fixture)
    make_workspace,
    nan_weights,
    pickled_depth,
    run_neo,
    scale_rotation,
    set_frame,
    set_scene,
    snapshot,
    temporaries,
)

BOX_FAR = {"center": [100.0, 0.0, 0.05], "size": [0.1, 0.1, 0.1], "yaw_deg": 0}
BOX_MUG = {"center": [0.076, -0.098, 0.046], "size": [0.074, 0.109, 0.09], "yaw_deg": 19.2}
LONG = "x" * 10_000


def write(name: str, content) -> Setup:
    return lambda ws: ws.write(name, content)


def neo_first(argv: str) -> Setup:
    """Run a neo command that must succeed (an earlier output the case then works on)."""

    def apply(ws: Workspace) -> None:
        from neoedit.cli import main

        args = [a.format(scene=ws.scene, data=ws.data, ws=ws.root) for a in shlex.split(argv)]
        quiet = contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO())
        with contextlib.chdir(ws.root), quiet[0], quiet[1]:
            assert main(args) == 0

    return apply


def cameras(**values) -> Setup:
    """cams.json: the dataset's transforms.json (cameras only) with global keys changed."""

    def apply(ws: Workspace) -> None:
        meta = ws.transforms()
        meta.update(values)
        ws.write("cams.json", meta)

    return apply


def cameras_frame(**values) -> Setup:
    def apply(ws: Workspace) -> None:
        meta = ws.transforms()
        meta["frames"][0].update(values)
        meta["frames"] = meta["frames"][:2]
        for key in ("train_filenames", "val_filenames", "test_filenames"):
            meta.pop(key)
        ws.write("cams.json", meta)

    return apply


NOTES = write("notes/todo.txt", "my notes")
FILE = write("notes.txt", "my notes")
MUG = write("mug.json", BOX_MUG)
FAR = write("far.json", BOX_FAR)
SPEC = write(
    "spec.yaml", "name: s\nobjects:\n  - {name: mug, urdf: 'pybullet_data:objects/mug.urdf'}\n"
)
EMPTY = lambda ws: ws.path("notes").mkdir()  # noqa: E731
SCENE2 = lambda ws: shutil.copytree(ws.scene, ws.path("scene2"))  # noqa: E731
TRAIN = " ".join(TINY_TRAIN_ARGS)


def OLD_RENDER(ws: Workspace) -> None:  # noqa: N802 (a setup constant, like the others)
    ws.write("r/images/old.png", b"old")
    mark_output(ws.path("r"), "render")


@dataclass
class C:
    id: str
    argv: str
    code: int
    fragment: str
    setup: Setup | None = None
    creates: tuple[str, ...] = ()
    """For a case that succeeds: paths it must write."""
    gone: tuple[str, ...] = ()
    """For a case that succeeds: paths it replaced."""


# one line per case
# fmt: off
CASES = [
    # 1. never destroy: an output equal to, inside or holding an input; anything not ours
    C("train-out-is-data", "train {data} --out {data} " + TRAIN, 2, "never overwrites its input"),
    C("train-out-in-data", "train {data} --out {data}/s " + TRAIN, 2, "inside the input"),
    C("train-out-holds-data", "train {data} --out {ws} " + TRAIN, 2, "holds the input"),
    C("train-out-user-folder", "train {data} --out notes " + TRAIN, 2, "not a neoedit output", NOTES),
    C("train-out-user-file", "train {data} --out notes.txt " + TRAIN, 2, "is a file", FILE),
    C("train-out-scene", "train {data} --out {scene} " + TRAIN, 2, "--resume"),
    C("train-resume-user-folder", "train {data} --out notes --resume " + TRAIN, 2, "not a neoedit output", NOTES),
    C("train-ok", "train {data} --out s " + TRAIN, 0, "wrote", creates=("s/scene.json",)),
    C("train-ok-empty-folder", "train {data} --out notes " + TRAIN, 0, "wrote", EMPTY, ("notes/field.safetensors",)),
    C("remove-overwrite-user-folder", "remove {scene} --box mug.json --out notes --overwrite --no-inpaint", 2, "not a neoedit output", chain(NOTES, MUG)),
    C("remove-overwrite-dataset", "remove {scene} --box mug.json --out {data} --overwrite --no-inpaint", 2, "not a neoedit output", MUG),
    C("remove-out-is-scene", "remove {scene} --box mug.json --out {scene} --no-inpaint", 2, "never overwrites", MUG),
    C("remove-out-in-scene", "remove {scene} --box mug.json --out {scene}/v --no-inpaint", 2, "inside the input", MUG),
    C("remove-exists", "remove {scene} --box mug.json --out scene2 --no-inpaint", 2, "already exists", chain(MUG, SCENE2)),
    C("remove-out-user-file", "remove {scene} --box mug.json --out notes.txt --no-inpaint", 2, "is a file; refusing", chain(FILE, MUG)),
    C("remove-ok", "remove {scene} --box mug.json --out v1 --no-inpaint --no-report", 0, "wrote", MUG, ("v1/scene.json",)),
    C("move-huge-yaw", "move {scene} --box mug.json --translate 0 0 0 --yaw 1e300 --out v", 2, "--yaw is in degrees", MUG),
    C("move-no-distill-rays", "move {scene} --box mug.json --translate 0.02 0 0 --out v --edit.distill.rays 0", 2, "--edit.distill.rays must be", MUG),
    C("move-seal3d-preview", "move {scene} --box mug.json --translate 0.02 0 0 --out v --method seal3d --preview", 2, "do not combine", MUG),
    C("move-seal3d-neo-option", "move {scene} --box mug.json --translate 0.02 0 0 --out v --method seal3d --edit.remove.margin-m 0.05", 2, "--edit.* options set NEO's move", MUG),
    C("move-neo-seal3d-option", "move {scene} --box mug.json --translate 0.02 0 0 --out v --seal3d.margin-m 0.05", 2, "add --method seal3d", MUG),
    C("move-seal3d-bad-schedule", "move {scene} --box mug.json --translate 0.02 0 0 --out v --method seal3d --seal3d.schedule.rays 0", 2, "--seal3d.schedule.rays must be", MUG),
    C("move-seal3d-negative-margin", "move {scene} --box mug.json --translate 0.02 0 0 --out v --method seal3d --seal3d.margin-m -1", 2, "--seal3d.margin-m must be", MUG),
    C("move-no-distill-steps", "move {scene} --box mug.json --translate 0.02 0 0 --out v --edit.distill.field-steps 0 --edit.distill.render-steps 0", 2, "nothing would learn", MUG),
    C("render-overwrite-dataset", "render {scene} --out {data} --overwrite", 2, "not a neoedit output"),
    C("render-overwrite-scene", "render {scene} --out scene2 --overwrite", 2, "a neoedit scene", SCENE2),
    C("render-overwrite-file", "render {scene} --out notes.txt --overwrite", 2, "is a file", FILE),
    C("render-in-scene", "render {scene} --out {scene}/r", 2, "inside the input"),
    C("render-overwrite-render", "render {scene} --out r --views eval --overwrite", 0, "wrote 3 views", OLD_RENDER, ("r/transforms.json",), ("r/images/old.png",)),
    C("render-ok", "render {scene} --out r --views eval", 0, "wrote 3 views", creates=("r/transforms.json",)),
    C("eval-json-over-transforms", "eval {scene} --data {data} --json {data}/transforms.json", 2, "inside the input"),
    C("eval-json-over-notes", "eval {scene} --data {data} --json notes.txt", 2, "not a previous JSON result", FILE),
    C("eval-json-over-folder", "eval {scene} --data {data} --json notes", 2, "not a previous JSON result", NOTES),
    C("eval-images-user-folder", "eval {scene} --data {data} --images notes --overwrite", 2, "(choose another --images)", NOTES),
    C("eval-images-in-scene", "eval {scene} --data {data} --images {scene}/img", 2, "inside the input"),
    C("eval-json-replaces-result", "eval {scene} --data {data} --json m.json --overwrite", 0, "psnr", write("m.json", {"old": 1}), ("m.json",)),
    C("eval-json-keeps-user-json", "eval {scene} --data {data} --json config.json", 2, "already exists", write("config.json", {"lr": 1})),
    C("eval-ok", "eval {scene} --data {data} --json m.json --images img", 0, "psnr", creates=("m.json", "img")),
    C("query-json-over-image", "query {scene} mug --json {ws}/notes.txt --views 0", 2, "not a previous JSON result", FILE),
    C("query-out-user-folder", "query {scene} mug --out notes", 2, "not a neoedit output", NOTES),
    C("query-bad-trim", "query {scene} mug --query.trim 0.7", 2, "--query.trim must be in"),
    C("remove-bad-query-option", "remove {scene} mug --out v1 --query.elongation 0.5", 2, "--query.elongation must be"),
    C("sim-scene-over-user-folder", "sim scene spec.yaml --out notes --overwrite", 2, "not a neoedit output", chain(SPEC, NOTES)),
    C("sim-scene-over-scene", "sim scene spec.yaml --out {scene} --overwrite", 2, "a neoedit scene", SPEC),
    C("sim-benchmark-over-file", "sim benchmark --profile small --only removal_1 --out notes.txt", 2, "not a folder", FILE),
    C("sim-benchmark-scene-over-folder", "sim benchmark --profile small --only removal_1 --out {ws} --overwrite", 2, "holds no earlier", write("removal_1/x.txt", "mine")),
    C("sim-benchmark-negative-seed", "sim benchmark --profile small --seed -1 --out b", 2, "--seed"),
    # 2. intrinsics and poses
    C("info-negative-focal", "info {data}", 2, "focal length 'fl_x' must be positive", set_frame(fl_x=-46.1)),
    C("info-zero-focal", "info {data}", 2, "focal length 'fl_y' must be positive", set_frame(fl_y=0)),
    C("train-zero-focal", "train {data} --out s " + TRAIN, 2, "must be positive", set_frame(fl_x=0)),
    C("info-nan-focal", "info {data}", 2, "'fl_x' must be a finite number", set_frame(fl_x=float("nan"))),
    C("info-frame-focal", "info {data}", 2, "frame 3: focal length", set_frame(3, fl_x=-1)),
    C("info-far-principal-point", "info {data}", 2, "principal point 'cx'", set_frame(cx=1e6)),
    C("info-fractional-width", "info {data}", 2, "whole number of pixels", set_frame(w=64.5)),
    C("info-zero-height", "info {data}", 2, "'h' must be a whole number", set_frame(h=0)),
    C("info-string-focal", "info {data}", 2, "finite number", set_frame(fl_x="46")),
    C("info-scaled-rotation", "info {data}", 2, "not orthonormal", scale_rotation(3.0)),
    C("info-mirrored-rotation", "info {data}", 2, "mirror", scale_rotation(-1.0)),
    C("info-singular-pose", "info {data}", 2, "not invertible", scale_rotation(0.0)),
    C("info-pose-3x3", "info {data}", 2, "4x4", set_frame(0, transform_matrix=np.eye(3).tolist())),
    C("info-pose-text", "info {data}", 2, "numeric matrix", set_frame(0, transform_matrix="identity")),
    C("info-pose-bottom-row", "info {data}", 2, "last row", set_frame(0, transform_matrix=[[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 1, 1]])),
    C("render-cameras-negative-focal", "render {scene} --cameras cams.json --out r", 2, "must be positive", cameras(fl_x=-5)),
    # 4. impossible options
    C("train-negative-steps", "train {data} --out s --max-steps -5", 2, "--max-steps must be at least 1, got -5"),
    C("train-zero-steps", "train {data} --out s --max-steps 0", 2, "--max-steps must be at least 1, got 0"),
    C("train-zero-minutes", "train {data} --out s --max-minutes 0", 2, "--max-minutes"),
    C("train-nan-lr", "train {data} --out s --lr nan", 2, "--lr must be a finite number"),
    C("train-zero-pose-lr", "train {data} --out s --pose-refinement --pose-lr 0", 2, "--pose-lr must be > 0"),
    C("train-zero-rays", "train {data} --out s --rays-per-batch 0", 2, "--rays-per-batch"),
    C("train-negative-eval-views", "train {data} --out s --eval-views -1", 2, "--eval-views"),
    C("train-zero-hidden", "train {data} --out s --field.hidden-dim 0", 2, "--field.hidden-dim = 0 is out of range"),
    C("train-huge-hash", "train {data} --out s --field.hashgrid.log2-hashmap-size 64", 2, "--field.hashgrid.log2-hashmap-size = 64"),
    C("train-bad-backend", "train {data} --out s --field.hashgrid.backend banana", 2, "backend"),
    C("train-zero-grid", "train {data} --out s --grid.resolution 0", 2, "resolution"),
    C("train-zero-samples", "train {data} --out s --render.n-samples 0", 2, "--render.n-samples = 0"),
    C("train-bad-teacher", "train {data} --out s --language.teacher banana", 2, "--language.teacher"),
    C("train-missing-clip", "train {data} --out s --language.clip-path /nonexistent/clip", 2, "does not exist"),
    C("train-resume-nothing-to-do", "train {data} --out {scene} --resume --max-steps 1 --skip-language", 2, "nothing to do"),
    C("train-not-a-number", "train {data} --out s --max-steps many", 2, ""),
    # 5. camera models
    C("render-cameras-banana-model", "render {scene} --cameras cams.json --out r", 2, "camera_model 'BANANA'", cameras(camera_model="BANANA")),
    C("render-cameras-fisheye", "render {scene} --cameras cams.json --out r", 2, "OPENCV_FISHEYE", cameras(camera_model="OPENCV_FISHEYE")),
    C("info-equirectangular", "info {data}", 2, "camera_model", set_frame(camera_model="EQUIRECTANGULAR")),
    C("info-frame-model", "info {data}", 2, "frame 2: camera_model", set_frame(2, camera_model="FISHEYE")),
    C("info-distortion", "info {data}", 2, "lens distortion", set_frame(k1=0.1)),
    C("info-distortion-text", "info {data}", 2, "'k1' must be a finite number", set_frame(k1="x")),
    C("render-cameras-opencv-ok", "render {scene} --cameras cams.json --out r", 0, "wrote 2 views", cameras_frame(camera_model="OPENCV"), ("r/transforms.json",)),
    # 7. broken weights
    C("render-nan-weights", "render {scene} --out r", 2, "NaN or infinite", nan_weights),
    C("eval-nan-weights", "eval {scene} --data {data}", 2, "NaN or infinite", nan_weights),
    C("remove-nan-weights", "remove {scene} --box mug.json --out v --no-inpaint", 2, "NaN or infinite", chain(MUG, nan_weights)),
    C("render-truncated-weights", "render {scene} --out r", 2, "cannot read weights", lambda ws: (ws.scene / "field.safetensors").write_bytes(b"\x08\x00")),
    C("render-missing-weights", "render {scene} --out r", 2, "missing field.safetensors", lambda ws: (ws.scene / "field.safetensors").unlink()),
    # 8. no tracebacks
    C("render-device-banana", "render {scene} --out r --device banana", 2, "not a device"),
    C("train-device-banana", "train {data} --out s --device banana", 2, "not a device"),
    C("eval-device-banana", "eval {scene} --data {data} --device banana", 2, "not a device"),
    C("remove-device-cuda-7", "remove {scene} --box mug.json --out v --device cuda:7", 2, "--device cuda:7", MUG),
    C("info-pickled-depth", "info {data}", 2, "cannot read depth", pickled_depth),
    C("info-depth-wrong-size", "info {data}", 2, "depth, mask or instance image", chain(write("data/depth/small.npy", np.ones((4, 4))), set_frame(1, depth_file_path="depth/small.npy"))),
    C("info-depth-text", "info {data}", 2, "cannot read depth", chain(write("data/depth/t.npy", b"not numpy"), set_frame(1, depth_file_path="depth/t.npy"))),
    C("info-binary-transforms", "info {data}", 2, "not valid JSON", write("data/transforms.json", b"\xff\xfe\x00garbage")),
    C("info-deep-transforms", "info {data}", 2, "not valid JSON", write("data/transforms.json", "[" * 100_000)),
    C("info-frames-not-list", "info {data}", 2, "non-empty 'frames' list", set_frame(frames={"a": 1})),
    C("info-file-path-number", "info {data}", 2, "'file_path' must be a non-empty path", set_frame(0, file_path=7)),
    C("info-missing-image", "info {data}", 2, "image not found", set_frame(0, file_path="images/nope.png")),
    C("info-background-text", "info {data}", 2, "background_color", set_frame(background_color="red")),
    C("info-flat-scene-box", "info {data}", 2, "scene_aabb", set_frame(scene_aabb=[[0, 0, 0], [1, 1, 0]])),
    C("info-split-not-list", "info {data}", 2, "'train_filenames' must be a list", set_frame(train_filenames=3)),
    C("info-bad-objects", "info {data}", 2, "'objects' must be a list", write("data/objects.json", {"instances": [], "objects": [1]})),
    C("info-depth-unit-zero", "info {data}", 2, "depth_unit_scale_factor", set_frame(depth_unit_scale_factor=0)),
    C("info-markup-in-path", "info '{ws}/[/]nope'", 2, "dataset not found"),
    C("info-missing", "info {ws}/nope", 2, "dataset not found"),
    # 9. renders: bounded, inside OUT
    C("render-too-many-frames", "render {scene} --views spiral --n-frames 100000 --out r", 2, "--n-frames must be between 1 and"),
    C("render-zero-frames", "render {scene} --views spiral --n-frames 0 --out r", 2, "--n-frames"),
    C("render-cameras-escape", "render {scene} --cameras cams.json --out r", 2, "stay inside", cameras_frame(file_path="../../escaped.png")),
    C("render-cameras-absolute", "render {scene} --cameras cams.json --out r", 2, "stay inside", cameras_frame(file_path="/tmp/escaped.png")),
    C("render-cameras-duplicate", "render {scene} --cameras cams.json --out r", 2, "name the same image", lambda ws: cameras_frame(file_path=ws.transforms()["frames"][1]["file_path"])(ws)),
    C("render-cameras-same-stem", "render {scene} --cameras cams.json --out r", 2, "share a file_path", lambda ws: cameras_frame(file_path=ws.transforms()["frames"][1]["file_path"].replace(".png", ".jpg"))(ws)),
    C("render-cameras-missing", "render {scene} --cameras nope.json --out r", 2, "file not found"),
    # 10. removal boxes
    C("remove-box-far-away", "remove {scene} --box far.json --out v --no-inpaint", 2, "does not intersect the scene box", FAR),
    C("remove-box-already-cut", "remove {scene} --box mug.json --out v --no-inpaint", 2, "holds nothing", chain(MUG, set_scene(cut_boxes=[{"center": [0.076, -0.098, 0.046], "size": [0.3, 0.3, 0.3], "yaw_deg": 0}]))),
    C("remove-box-malformed", "remove {scene} --box bad.json --out v", 2, "bad.json: bad box", write("bad.json", {"center": [0, 0]})),
    C("remove-box-flat", "remove {scene} --box flat.json --out v", 2, "flat.json: box size must be positive", write("flat.json", {"center": [0, 0, 0.1], "size": [0.1, 0.1, 0], "yaw_deg": 0})),
    C("remove-box-negative-size", "remove {scene} --box bad.json --out v", 2, "size must be positive", write("bad.json", {"center": [0, 0, 0], "size": [-1, 1, 1]})),
    C("remove-box-missing", "remove {scene} --box nope.json --out v", 2, "box file not found"),
    C("remove-prompt-and-box", "remove {scene} mug --box mug.json --out v", 2, "not two", MUG),
    C("remove-no-target", "remove {scene} --out v", 2, "none was given"),
    C("remove-masks-not-a-folder", "remove {scene} --masks mug.json --out v", 2, "not a folder", MUG),
    C("remove-masks-unmatched", "remove {scene} --masks m --out v --no-inpaint", 2, "no mask is named after a photo", write("m/unrelated.png", b"")),
    # 11. scene.json
    C("render-flat-aabb", "render {scene} --out r", 2, "aabb_m", lambda ws: set_scene(aabb_m=[ws.scene_json()["aabb_m"][0]] * 2)(ws)),
    C("render-nan-aabb", "render {scene} --out r", 2, "aabb_m", set_scene(aabb_m=[[0, 0, 0], [1, 1, float("nan")]])),
    C("render-moved-aabb", "render {scene} --out r", 2, "not the box the field was trained on", set_scene(aabb_m=[[0, 0, 0], [1, 1, 1]])),
    C("render-bad-background", "render {scene} --out r", 2, "background_rgb", set_scene(background_rgb=[2, 0, 0])),
    C("render-zero-samples-json", "render {scene} --out r", 2, "render.n_samples", lambda ws: set_scene(render={**ws.scene_json()["render"], "n_samples": 0})(ws)),
    C("render-config-mismatch", "render {scene} --out r", 2, "do not match the scene config", lambda ws: set_scene(field={**ws.scene_json()["field"], "hidden_dim": 9})(ws)),
    C("render-grid-mismatch", "render {scene} --out r", 2, "grid.density", lambda ws: set_scene(grid={**ws.scene_json()["grid"], "resolution": 1000})(ws)),
    C("render-bad-cut-box", "render {scene} --out r", 2, "cut_boxes: bad box", set_scene(cut_boxes=[{"center": 1}])),
    C("render-wrong-format", "render {scene} --out r", 2, "unsupported scene format", set_scene(format="neoedit.scene/99")),
    C("render-truncated-json", "render {scene} --out r", 2, "not valid JSON", write("scene/scene.json", '{"format": ')),
    C("render-not-a-scene", "render {data} --out r", 2, "not a neoedit scene"),
    C("render-missing-scene", "render {ws}/nope --out r", 2, "scene not found"),
    C("eval-missing-data", "eval {scene} --data {ws}/nope", 2, "dataset not found"),
    # 13. long prompts are shortened in messages
    C("remove-long-prompt", f"remove {{scene}} {LONG} --out v", 2, "no language field"),
    C("query-long-prompt", f"query {{scene}} {LONG} --views 0", 2, "no language field"),
    C("query-empty-prompt", "query {scene} ' ; '", 2, "empty prompt"),
    C("query-negative-views", "query {scene} mug --views -1", 2, "--views"),
    # 14. issue 42: options by range in one place; parse errors one short message
    C("no-arguments", "", 2, "Expected one of"),
    C("unknown-option-short", "move {scene} --box mug.json --out v --steps 5", 2, "did you mean", MUG),
    C("query-eps-inf", "query {scene} mug --query.eps-m inf", 2, "--query.eps-m must be a finite number"),
    C("query-no-canonical", "query {scene} mug --query.canonical", 2, "--query.canonical needs"),
    C("grasp-nan-width", "grasp {scene} mug --grasp.min-width-m nan", 2, "--grasp.min-width-m must be a finite"),
    C("grasp-min-width-beyond-opening", "grasp {scene} mug --grasp.min-width-m 1e9", 2, "must be below the gripper's widest opening"),
    C("move-nan-translate", "move {scene} --box mug.json --translate 0.1 0 nan --out v", 2, "--translate must be finite", MUG),
    C("bench-negative-seed", "bench --out b --seed -1", 2, "--seed must be a whole number in [0, 2^32)"),
    C("bench-seed-past-numpy", "bench --out b --seed 4294967296", 2, "--seed must be a whole number in [0, 2^32), got 4294967296"),
    C("bench-ray-unreachable", "bench --out b --scenes removal_1 --methods pre-edit --ray 127.0.0.1:1", 2, "cannot reach the Ray cluster"),
    C("bench-ray-malformed", "bench --out b --ray nowhere", 2, "--ray must be"),
    # 15. files a user hands a command: bounded, regular, parsed with one message
    C("plan-dev-zero", "plan {scene} /dev/zero --out st", 2, "the plan must be a file"),
    C("plan-folder", "plan {scene} {ws} --out st", 2, "the plan must be a file (a folder)"),
    C("plan-binary", "plan {scene} p.yaml --out st", 2, "not UTF-8 text", write("p.yaml", b"\xff\xfe\x00")),
    C("plan-step-2-yaw", "plan {scene} p.json --out st", 2, "step 2: yaw_deg is in degrees", write("p.json", [{"type": "remove", "box": BOX_MUG}, {"type": "move", "box": BOX_MUG, "yaw_deg": 720}])),
    # the fifth probe (batch plans): nested preview switches, a batch's boxes that overlap and
    # a given box moved out of the scene, refused before the store is written
    C("remove-huge-turns", "remove {scene} --box mug.json --out v --views.turns 100000", 2, "--views.turns must be <= 16, got 100000", MUG),
    C("move-translate-two", "move {scene} --box mug.json --translate 0.1 0 --out v", 2, "error: --translate takes 3 values, got 2 ", MUG),
    C("move-translate-word", "move {scene} --box mug.json --translate 0.1 a 0 --out v", 2, "error: --translate takes 3 numbers ", MUG),
    C("move-json-in-out", "move {scene} --box mug.json --translate 0.02 0 0 --out v --json v/r.json", 2, "is inside the output v", MUG),
    C("plan-preview-ignored", "plan {scene} p.json --out st --preview --edit.remove.refine.steps 5", 2, "a preview's removals are cuts: --edit.remove.refine.steps would be ignored", write("p.json", [{"type": "remove", "box": BOX_MUG}])),
    C("move-preview-ignored", "move {scene} --box mug.json --translate 0.02 0 0 --out v --preview --edit.student field", 2, "a preview trains nothing: --edit.student would be ignored", MUG),
    C("move-nested-preview", "move {scene} --box mug.json --translate 0.02 0 0 --out v --edit.preview", 2, "neo move has no --edit.preview", MUG),
    C("plan-nested-preview", "plan {scene} p.json --out st --edit.move.preview", 2, "Unrecognized options: --edit.move.preview", write("p.json", [{"type": "move", "box": BOX_MUG, "translate_m": [0.02, 0, 0]}])),
    C("plan-edit-preview", "plan {scene} p.json --out st --edit.preview", 2, "--edit.preview is set by --preview", write("p.json", [{"type": "remove", "box": BOX_MUG}])),
    # the sixth probe: plan lists of the wrong length, a --transform checked before the
    # query, a --threads without its value, a mistyped verb named as one (tyro: an option)
    C("plan-short-translation", "plan {scene} p.json --out st", 2, "step 2: translate_m: takes 3 numbers [x, y, z], got 2", write("p.json", [{"type": "remove", "box": BOX_MUG}, {"type": "move", "box": BOX_MUG, "translate_m": [0.02, 0]}])),
    C("plan-long-translation", "plan {scene} p.json --out st", 2, "step 1: translate_m: takes 3 numbers [x, y, z], got 4", write("p.json", [{"type": "move", "box": BOX_MUG, "translate_m": [0.02, 0, 0, 1]}])),
    C("move-scaled-transform-before-query", "move {scene} mug --transform t.json --out v", 2, "t.json: the transform must be a finite rigid motion", write("t.json", [[2, 0, 0, 0], [0, 2, 0, 0], [0, 0, 2, 0], [0, 0, 0, 1]])),
    C("threads-missing-value", "--threads train {data} --out s", 2, "--threads must be a positive integer, got 'train'"),
    C("unknown-verb", "trian {data} --out s", 2, "'trian' is not a neo command; did you mean 'train'?"),
    C("plan-batch-overlap", "plan {scene} p.json --out st --preview", 2, "step 1 (batch (remove box, move box)): edits 1 (remove) and 2 (move) of the batch touch the same place", write("p.json", [{"type": "batch", "edits": [{"type": "remove", "box": BOX_MUG}, {"type": "move", "box": BOX_MUG, "translate_m": [0.02, 0, 0]}]}])),
    C("plan-batch-move-out", "plan {scene} p.json --out st --preview", 2, "leaves the scene box", write("p.json", [{"type": "batch", "edits": [{"type": "move", "box": BOX_MUG, "translate_m": [0, 0, -0.5]}]}])),
    C("train-too-short-for-language", "train {data} --out s " + TRAIN.replace("--skip-language", ""), 0, "language", None, ("s/scene.json",)),
    C("train-seed-not-whole", "train {data} --out s --seed 1e20", 2, "--seed takes a whole number"),
    C("train-lr-not-a-number", "train {data} --out s --lr abc", 2, "--lr takes a number"),
    C("plan-duplicate-key", "plan {scene} p.yaml --out st", 2, "line 1, column 53: the key 'edits' is given twice", write("p.yaml", "- {type: batch, edits: [{type: remove, prompt: a}], edits: []}\n")),
    C("remove-box-duplicate-key", "remove {scene} --box b.json --out v", 2, "the key 'center' is given twice", write("b.json", '{"center": [0, 0, 0.05], "size": [0.1, 0.1, 0.1], "center": [0.1, 0, 0.05]}')),
    C("plan-seal3d-preview", "plan {scene} p.json --out st --method seal3d --preview", 2, "do not combine", write("p.json", [{"type": "move", "box": BOX_MUG, "translate_m": [0.02, 0, 0]}])),
    C("plan-seal3d-neo-option", "plan {scene} p.json --out st --method seal3d --edit.move.distill.rays 8", 2, "--edit.move.* options set NEO's move", write("p.json", [{"type": "move", "box": BOX_MUG, "translate_m": [0.02, 0, 0]}])),
    C("plan-bad-move-option", "plan {scene} p.json --out st --edit.move.distill.rays 0", 2, "--edit.move.distill.rays must be", write("p.json", [{"type": "remove", "box": BOX_MUG}, {"type": "move", "box": BOX_MUG, "translate_m": [0.02, 0, 0]}])),
    C("plan-step-2-far", "plan {scene} p.json --out st", 2, "step 2 (move box): a move of 25.00 m leaves the scene box", write("p.json", [{"type": "remove", "box": BOX_MUG}, {"type": "move", "box": BOX_MUG, "translate_m": [25, 0, 0]}])),
    C("plan-step-2-empty-prompt", "plan {scene} p.json --out st", 2, "step 2: the prompt is empty", write("p.json", [{"type": "remove", "box": BOX_MUG}, {"type": "remove", "prompt": " "}])),
    C("plan-step-2-motions", "plan {scene} p.json --out st", 2, "1 object(s) but 2 motions", write("p.json", [{"type": "remove", "box": BOX_MUG}, {"type": "move", "prompt": "mug", "motions": [{"yaw_deg": 5}, {"yaw_deg": 9}]}])),
    C("plan-step-2-box-outside", "plan {scene} p.json --out st", 2, "step 2 (remove box)", write("p.json", [{"type": "remove", "box": BOX_MUG}, {"type": "remove", "box": BOX_FAR}])),
    C("move-transform-dev-zero", "move {scene} --box mug.json --transform /dev/zero --out v", 2, "must be a file", MUG),
    C("sim-scene-radius-zero", "sim scene spec.yaml --out s", 2, "'scan.radius_m'", write("spec.yaml", "name: s\nobjects:\n  - {name: mug, urdf: 'pybullet_data:objects/mug.urdf'}\nscan: {radius_m: 0}\n")),
    C("sim-scene-huge-width", "sim scene spec.yaml --out s", 2, "8 to 4096 pixels", write("spec.yaml", "name: s\nobjects:\n  - {name: mug, urdf: 'pybullet_data:objects/mug.urdf'}\nscan: {width: 1000000}\n")),
    C("sim-execute-malformed", "sim execute bad --action 1 --grasp g.json --out e", 2, "not a NEO-Sim scene folder", chain(write("bad/scene.json", [1, 2]), write("g.json", {"position_m": [0, 0, 0.1], "rotation": np.eye(3).tolist(), "width_m": 0.05}))),
    C("render-overwrite-keeps-user-file", "render {scene} --out r --views eval --overwrite", 2, "holds files neoedit did not write (images/mine.txt)", chain(neo_first("render {scene} --out r --views eval"), write("r/images/mine.txt", "my notes"))),
    C("remove-overwrite-keeps-user-file", "remove {scene} --box mug.json --out v --no-inpaint --overwrite", 2, "holds files neoedit did not write (notes.txt)", chain(MUG, neo_first("remove {scene} --box mug.json --out v --no-inpaint --no-report"), write("v/notes.txt", "mine"))),
    # 16. a render never overwrites its own outputs
    C("render-cameras-named-transforms", "render {scene} --cameras cams.json --out r", 2, "would overwrite the render's own transforms.json", cameras_frame(file_path="transforms.json")),
    C("render-cameras-under-depth", "render {scene} --cameras cams.json --out r", 2, "would overwrite the render's own depth", cameras_frame(file_path="depth/x.png")),
    # 17. the second probe of issue 42: options under omitted prefixes named as typed, an edit
    # that would not train refused, one object moved once, a view too big for memory
    C("remove-zero-steps", "remove {scene} --box mug.json --out v --refine.steps 0", 2, "--refine.steps must be >= 1, got 0", MUG),
    C("remove-zero-rounds", "remove {scene} --box mug.json --out v --refine.rounds 0", 2, "--refine.rounds must be >= 1, got 0", MUG),
    C("remove-zero-turns", "remove {scene} --box mug.json --out v --views.turns 0", 2, "--views.turns must be >= 1, got 0", MUG),
    C("remove-negative-reach", "remove {scene} --box mug.json --out v --shadow.reach -1", 2, "--shadow.reach must be", MUG),
    C("remove-unknown-removal", "remove {scene} --box mug.json --out v --removal bogus", 2, "--removal 'bogus' is unknown", MUG),
    C("move-unknown-removal", "move {scene} --box mug.json --translate 0.01 0 0 --out v --edit.remove.removal bogus", 2, "--edit.remove.removal 'bogus' is unknown", MUG),
    C("move-zero-refine-steps", "move {scene} --box mug.json --translate 0.01 0 0 --out v --edit.remove.refine.steps 0", 2, "--edit.remove.refine.steps must be >= 1, got 0", MUG),
    C("move-one-object-twice", "move {scene} --box mugs.json --translate 0.01 0 0 --out v", 2, "start from the same region", write("mugs.json", [BOX_MUG, BOX_MUG])),
    C("move-short-translate", "move {scene} --box mug.json --translate 1 2 --out v", 2, "--translate takes 3 values, got 2", MUG),
    C("render-view-beyond-memory", "render {scene} --cameras cams.json --out r", 2, "GiB of memory", cameras(w=32768, h=32768, cx=16384.0, cy=16384.0)),
    # 18. the third probe of issue 42: one range per option whatever the value, the conflict
    # named as the user meets it, the thing at a path named for what it is
    C("threads-beyond-machine", "info {data} --threads 100000", 2, "give at most"),
    C("grasp-top-zero", "grasp {scene} mug --top 0", 2, "--top must be >= 1, got 0"),
    C("grasp-top-negative", "grasp {scene} mug --top -1", 2, "--top must be >= 1, got -1"),
    C("grasp-contacts-zero", "grasp {scene} mug --grasp.contacts 0", 2, "--grasp.contacts must be >= 1"),
    C("render-zero-frames-one-rule", "render {scene} --n-frames 0 --out r", 2, "--n-frames must be >= 1, got 0"),
    C("diff-zero-views", "diff {scene} a b --views 0", 2, "--views must be >= 1, got 0"),
    C("query-huge-image-scale", "query {scene} mug --image-scale 1000", 2, "--image-scale must be in (0, 4], got 1000"),
    C("train-room-on-rgba", "train {data} --out s --field.room True " + TRAIN, 2, "transparent backgrounds"),
    C("train-room-closed-bottom", "train {data} --out s --field.room True --field.closed-bottom " + TRAIN, 2, "rules out --field.closed-bottom"),
    C("train-no-overwrite-option", "train {data} --out s --overwrite " + TRAIN, 2, "neo train has no --overwrite"),
    C("train-out-store", "train {data} --out st " + TRAIN, 2, "is a scene store", write("st/store.json", {"format": "neoedit.store/1", "current": None})),
    C("log-file", "log notes.txt", 2, "notes.txt is a file", FILE),
    C("log-store-without-current", "log st", 0, "names 'step_9' as current, which is not a version", write("st/store.json", {"format": "neoedit.store/1", "current": "step_9"})),
    C("global-camera-model", "info {data}", 2, "transforms.json: camera_model 'FISHEYE_ODD'", set_frame(None, camera_model="FISHEYE_ODD")),
    C("plan-yaml-syntax", "plan {scene} p.yaml --out st", 2, "not valid YAML: line 3, column 4: expected <block end>", write("p.yaml", "steps:\n  - type: remove\n   box: [1,2\n")),
    C("flag-given-a-value", "train {data} --out s --field.closed-bottom True " + TRAIN, 2, "takes no True/False after it"),
    C("verbose-and-quiet", "info {data} --verbose --quiet", 2, "opposite logs"),
    # 19. the fourth probe of issue 42: numbers beyond any sane size, a training that cannot
    # fit or diverges, a resume that would drop options, a value swallowed as the prompt
    C("train-huge-seed", "train {data} --out s --seed 99999999999999999999 " + TRAIN, 2, "--seed must be a whole number in [0, 2^32)"),
    C("train-huge-density-bias", "train {data} --out s --field.density-bias 1e300 " + TRAIN, 2, "--field.density-bias must be at most 1e+12"),
    C("train-rays-beyond-memory", "train {data} --out s --rays-per-batch 100000000 --max-steps 1", 2, "GiB of memory"),
    C("train-diverges", "train {data} --out s --lr 1e9 " + TRAIN, 2, "training diverged "),
    C("train-resume-other-model", "train {data} --out r --resume --max-steps 3 --skip-language --field.hidden-dim 16", 2, "--field.hidden-dim 16 differs from its saved 8", neo_first("train {data} --out r " + TRAIN)),
    C("grasp-up-zero", "grasp {scene} --box mug.json --grasp.up 0 0 0", 2, "give a non-zero vector", MUG),
    C("grasp-negative-path", "grasp {scene} --box mug.json --grasp.approach-path-m -1", 2, "--grasp.approach-path-m must be >= 0", MUG),
    C("remove-flag-given-true", "remove {scene} --box mug.json --out v --no-inpaint true", 2, "--no-inpaint takes no value", MUG),
    C("remove-flag-equals-false", "remove {scene} --box mug.json --out v --inpaint=False", 2, "write --no-inpaint", MUG),
    C("move-own-option-suggested", "move {scene} --box mug.json --translate 0.01 0 0 --out v --no-inpaint", 2, "did you mean: --edit.remove.no-inpaint", MUG),
    C("plan-empty-box-list", "plan {scene} p.yaml --out st", 2, "box is an empty list", write("p.yaml", "- {type: remove, box: []}\n")),
    C("eval-empty-box-list", "eval {scene} --data {data} --out-box be.json", 2, "be.json holds an empty list", write("be.json", [])),
    C("render-cameras-no-image-name", "render {scene} --cameras cams.json --out r", 2, "is no image name", cameras_frame(file_path="images/x.tif")),
    C("render-cameras-name-is-a-folder", "render {scene} --cameras cams.json --out r", 2, "is also the folder of another frame's", cameras_frame(file_path="images")),
    C("info-frames-twice", "info {data}", 2, "name the same image", lambda ws: ws.write_transforms({**ws.transforms(), "frames": ws.transforms()["frames"] * 2})),
    C("info-max-width-zero", "info {data} --max-width 0", 2, "--max-width must be >= 8, got 0"),
    C("view-port-zero", "view {scene} --port 0", 2, "--port = 0 is out of range [1, 65535]"),
    C("sim-scene-off-table", "sim scene spec.yaml --out s", 2, "fell off the table", write("spec.yaml", "name: s\nobjects:\n  - {name: mug, urdf: 'pybullet_data:objects/mug.urdf', position_m: [100, 0, 0.01]}\n")),
    C("sim-scene-nan-position", "sim scene spec.yaml --out s", 2, "'objects[0].position_m': must be finite", write("spec.yaml", "name: s\nobjects:\n  - {name: mug, urdf: 'pybullet_data:objects/mug.urdf', position_m: [.nan, 0, 0.01]}\n")),
]
# fmt: on


@pytest.mark.parametrize("case", CASES, ids=[c.id for c in CASES])
def test_case(case: C, golden, tmp_path: Path, capsys, monkeypatch) -> None:
    ws = make_workspace(tmp_path / "ws", *golden)
    if case.setup is not None:
        case.setup(ws)
    monkeypatch.chdir(ws.root)
    before = snapshot(ws.root)
    argv = [a.format(data=ws.data, scene=ws.scene, ws=ws.root) for a in shlex.split(case.argv)]
    res = run_neo(argv, capsys)
    assert res.traceback is None, res.traceback
    assert res.code == case.code, f"exit {res.code}: {res.err[:500]}"
    assert len(res.err) < 600, f"message too long ({len(res.err)} chars)"
    if case.code == 2 and case.fragment:
        assert res.err.count("error:") == 1 and case.fragment in res.err, res.err
    if case.code != 0:
        assert changes(before, snapshot(ws.root)) == [], "a refused command wrote or deleted"
    else:
        assert case.fragment in res.out.replace("\n", " ") + res.err
        assert all((ws.root / p).exists() for p in case.creates)
        assert not any((ws.root / p).exists() for p in case.gone)
    assert temporaries(ws.root) == []


def test_every_defect_has_cases() -> None:
    """Defects 1-13 of issue 12 each have at least one line in the table (3, 6 and 12 are
    tested below and in test_interrupted_writes.py: they need a broken disk or a kill)."""
    ids = " ".join(c.id for c in CASES)
    for word in ("out-is-data", "focal", "steps", "model", "nan-weights", "banana", "pickled",
                 "frames", "far-away", "flat-aabb", "long-prompt"):  # fmt: skip
        assert word in ids, word


def test_every_default_option_passes_the_range_rules() -> None:
    """The one range check (neoedit.utils.options) accepts every verb's defaults: a rule
    that refused a default would break a command nobody changed."""
    import dataclasses
    from typing import get_args

    from neoedit.cli import Commands
    from neoedit.utils.options import _default, check_options

    def commands(t) -> list[type]:
        found = []
        for a in get_args(t):
            if isinstance(a, type) and dataclasses.is_dataclass(a):
                found.append(a)
            elif get_args(a):
                found += commands(a)
        return found

    verbs = commands(Commands)
    assert len({v.__name__ for v in verbs}) >= 18
    checked = 0
    for verb in verbs:
        for f in dataclasses.fields(verb):
            value = _default(f)
            if dataclasses.is_dataclass(value):
                check_options(value, (f.name,))
                checked += 1
    assert checked >= 15


def test_log_of_an_edited_folder_lists_its_lineage_once(golden, tmp_path: Path, capsys) -> None:
    """``neo log`` on an edited scene folder: the trained scan first, then each edit once,
    the folder's own edit named by the folder (the fourth probe saw it twice, the scan
    never)."""
    from neoedit.cli import main

    ws = make_workspace(tmp_path / "ws", *golden)
    ws.write("mug.json", BOX_MUG)
    scan_id = ws.scene_json()["version_id"]
    out = ws.path("v1")
    assert (
        main(
            [
                "remove",
                str(ws.scene),
                "--box",
                str(ws.path("mug.json")),
                "--out",
                str(out),
                "--no-inpaint",
                "--no-report",
            ]
        )
        == 0
    )
    assert not (out / "report").exists()  # --no-report: the version alone
    edit_id = ws.path("v1/scene.json")
    capsys.readouterr()
    assert main(["log", str(out)]) == 0
    text = capsys.readouterr().out
    own = __import__("json").loads(edit_id.read_text())["version_id"]
    rows = [line for line in text.splitlines() if line.startswith("│")]
    assert sum(own[:8] in r for r in rows) == 1 and any(
        scan_id[:8] in r and "train" in r for r in rows
    )


def test_every_seed_numpy_accepts_is_accepted() -> None:
    """Seeds span [0, 2^32), numpy's range (the fourth probe's notes: they stopped at
    2^31 - 1, so `neo sim benchmark --seed 3000000000`, valid by its own help, was refused)."""
    import dataclasses

    from neoedit.errors import NeoError
    from neoedit.training.trainer import TrainConfig
    from neoedit.utils.options import check_options

    top = 2**32 - 1
    check_options(TrainConfig(seed=top))
    np.random.default_rng(top), np.random.RandomState(top)  # both take it
    for bad in (-1, 2**32):
        with pytest.raises(NeoError, match=r"--seed must be a whole number in \[0, 2\^32\)"):
            check_options(dataclasses.replace(TrainConfig(), seed=bad))
    # COLMAP's seed is a C int: its own narrower range, said as such
    from neoedit.data.sfm import SfMConfig

    check_options(SfMConfig(seed=2**31 - 1))
    with pytest.raises(NeoError, match=r"--seed must be a whole number in \[0, 2147483647\]"):
        check_options(SfMConfig(seed=2**31))
