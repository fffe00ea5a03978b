"""Predict, then act: grasps planned on NEO versions, executed by the simulated Panda, and
the executed outcome compared with the predicted version.

    neo bench --profile standard --data outputs/neosim_standard --out outputs/bench_standard \
        --scenes pick_place_1 pick_place_2 pick_place_3 pick_place_4 assembly \
        --methods neo --keep-versions
    python benchmarks/bench_grasp.py --bench outputs/bench_standard --out outputs/bench_grasp

Per object (NEO-Sim pick_place_1-4 and the 4 assembly steps): the object is found by name on
the version *before* the move (for assembly steps 2-4 an edited version), grasps are planned
on it (`neo grasp`, the best 20), those the arm reaches at every waypoint of the pick and the
place come first (`neo sim execute`'s kinematic check; `--no-reach-check`: the planner's
order), up to 5 are executed in that order in the scene's PyBullet world (replaying earlier
steps), and the first successful execution is scanned with the
scene's cameras. Figures: top-1 / top-5 success, planning time, placement error (position,
yaw) against the intended transform, and PSNR (Full, In) of the predicted version (`neo
move`'s output) against the executed outcome's held-out views. Held-out objects (the
other objects of those scenes, whose grasps were never looked at while the planner was
tuned): picked, held, shaken and put back down where they were. The same sampler on the
simulator's geometry (the convex parts each object collides with + the table slab) is the
upper bound row ("truth geometry").

Its inputs come from a ``neo bench`` run that kept its versions (the command above): the
trained pre scans, NEO's moved versions and the assembly's scene store.
"""

from __future__ import annotations

import argparse
import json
import platform
import shlex
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import torch
from scipy.spatial import Delaunay

from neoedit.bench.folder import RunFolder
from neoedit.cameras.rays import CameraTensors
from neoedit.data import load_scene_data
from neoedit.errors import NeoError
from neoedit.eval.evaluate import evaluate
from neoedit.geometry import OrientedBox
from neoedit.grasp import GraspConfig, plan_grasps
from neoedit.grasp.antipodal import scene_density
from neoedit.language.localize import query_scene
from neoedit.language.text import load_text_encoder
from neoedit.scene import load_scene
from neoedit.sim.execute import (
    ExecuteConfig,
    execute_action,
    execute_move,
    placement_error,
    reach_error,
    reachable_first,
)
from neoedit.sim.specfile import scene_spec_from_dict
from neoedit.sim.world import SimWorld
from neoedit.utils.io import write_png
from neoedit.viz.boxes import draw_box
from neoedit.viz.grasps import draw_grasps
from neoedit.viz.zoom import facing_view


def truth_density(scene_dir: Path, step: int):  # type: ignore[no-untyped-def]
    """Density of the simulator's geometry before action ``step``: the convex parts every
    object collides with (a mug's decomposition keeps its inside open), and the table top
    as a slab."""
    meta = json.loads((scene_dir / "scene.json").read_text())
    spec = scene_spec_from_dict(meta["spec"])
    with SimWorld(spec) as world:
        for a in spec.actions[: step - 1]:
            world.apply(a)
        hulls = [Delaunay(p) for name in world.bodies for p in world.collision_parts_world(name)]

    def density(points: torch.Tensor) -> torch.Tensor:
        p = points.numpy().astype(np.float64)
        inside = p[:, 2] <= 0.0
        for h in hulls:
            inside |= h.find_simplex(p) >= 0
        return torch.as_tensor(inside, dtype=torch.float32) * 2000.0

    return density


def attempt(scene_dir: Path, step: int, grasps: list, out: Path, reach: bool) -> dict:
    """Execute the top grasps in order until one succeeds; with ``reach``, those the arm
    reaches at every waypoint (kinematic check) come first, in the planner's order."""
    tries = []
    cfg = ExecuteConfig()
    dicts = [g.to_dict() for g in grasps]
    t0 = time.perf_counter()
    try:
        order = reachable_first(scene_dir, step, dicts, cfg) if reach else []
    except NeoError as e:  # e.g. the KUKA setup: no gripper to execute with
        return {"top1": False, "top5": False, "tries": [], "scan": None, "error": str(e)}
    ranks = [r.grasp for r in order] if reach else list(range(len(dicts)))
    check = {
        "reachable": sum(r.error_m <= cfg.reach_tolerance_m for r in order) if reach else None,
        "reach_check_s": round(time.perf_counter() - t0, 2),
    }
    for rank, index in enumerate(ranks[:5]):
        folder = out / f"attempt_{rank}"
        try:
            ex = execute_action(scene_dir, step, dicts[index], folder, cfg)
        except NeoError as e:  # e.g. the KUKA setup: no gripper to execute with
            return {"top1": False, "top5": False, "tries": [], "scan": None, "error": str(e)}
        record = json.loads((folder / "execution.json").read_text())
        tries.append(
            {"rank": rank, "planner_rank": index, "stage": ex.stage, "cause": ex.cause, **record}
        )
        if ex.success:
            done = {"top1": rank == 0, "top5": True, "tries": tries, "scan": str(folder / "scan")}
            return {**done, **check}
    return {"top1": False, "top5": False, "tries": tries, "scan": None, **check}


def figure(before, grasps: list, tried: list[int], predicted, scan: str | None, box) -> np.ndarray:  # type: ignore[no-untyped-def]
    """One row: the grasps the arm tried, in order (green, yellow, orange, ...), drawn over
    a render of the version they were planned on; then, from one held-out view of the
    executed outcome, the predicted version and what the robot really left."""
    cameras, _, split = before.scan_cameras()
    pool = np.asarray(split.get("train", np.arange(len(cameras))))
    i = facing_view(cameras, pool, np.asarray(box.center_m))
    h, w = int(cameras.height[i]), int(cameras.width[i])
    rgb = before.render_image(CameraTensors(cameras, before.field.aabb.device), i, h, w)["rgb"]
    img = draw_box(
        (rgb.clamp(0, 1).cpu().numpy() * 255).round().astype(np.uint8),
        cameras,
        i,
        box,
        (90, 90, 255),
        1,
    )
    tiles = [draw_grasps(img, cameras, i, [grasps[k] for k in tried], GraspConfig().gripper)]
    if scan is not None:
        data = load_scene_data(Path(scan))
        j = int(data.split["test"][0])
        cams = CameraTensors(data.cameras, predicted.field.aabb.device)
        h, w = data.images.shape[1:3]
        out = predicted.render_image(cams, j, h, w)["rgb"].clamp(0, 1).cpu().numpy()
        tiles += [(out * 255).round().astype(np.uint8), data.images[j]]
    while len(tiles) < 3:
        tiles.append(np.zeros_like(tiles[0]))
    size = tiles[0].shape[:2]
    tiles = [cv2.resize(t, (size[1], size[0]), interpolation=cv2.INTER_AREA) for t in tiles]
    return np.concatenate(tiles, axis=1)


def run_object(name: str, scene_dir: Path, step: int, before, predicted, args) -> dict:  # type: ignore[no-untyped-def]
    action = json.loads((scene_dir / "scene.json").read_text())["actions"][step - 1]
    text = load_text_encoder(before.meta.language.text)
    box = query_scene(before, action["object"], text).box
    row: dict = {"object": action["object"]}
    for label, density in (
        ("neo", scene_density(before)),
        ("truth geometry", truth_density(scene_dir, step)),
    ):
        t0 = time.perf_counter()
        grasps = plan_grasps(density, box, GraspConfig(), top_k=args.candidates)
        seconds = time.perf_counter() - t0
        out = args.out / name / label.replace(" ", "_")
        res = (
            attempt(scene_dir, step, grasps, out, not args.no_reach_check)
            if grasps
            else {"top1": False, "top5": False, "tries": [], "scan": None}
        )
        res["plan_s"] = round(seconds, 2)

        res["n_grasps"] = len(grasps)
        if res["scan"] is not None and label == "neo":
            done = res["tries"][-1]
            res["placement_error"] = done.get("placement_error")
            target = OrientedBox.from_dict(action["target_box"])
            data = load_scene_data(Path(res["scan"]))
            m = evaluate(predicted, data, "test", [], [target], max_views=args.views)
            res["prediction_vs_outcome"] = {"full": m["full"]["psnr"], "in": m["in"]["psnr"]}
        if label == "neo":
            tried = [t["planner_rank"] for t in res["tries"]]
            res["figure"] = figure(before, grasps, tried, predicted, res["scan"], box)
        row[label] = res
        print(
            f"{name:24s} {label:15s} grasps {len(grasps)}  top1 {res['top1']}  top5 {res['top5']}  "
            f"plan {seconds:.1f} s  reachable {res.get('reachable')}/{len(grasps)}  "
            f"{res.get('placement_error', '')}  {res.get('prediction_vs_outcome', '')}",
            flush=True,
        )
    return row


def put_back(scene_dir: Path, obj: str, before, args) -> dict:  # type: ignore[no-untyped-def]
    """A held-out object (no failure of it was looked at while tuning the planner): grasps
    planned on the pre version, the first the arm reaches executed with an identity move
    (lift, hold, shake, put back down where it was), up to 5 tries."""
    spec = scene_spec_from_dict(json.loads((scene_dir / "scene.json").read_text())["spec"])
    box = query_scene(before, obj, load_text_encoder(before.meta.language.text)).box
    t0 = time.perf_counter()
    grasps = plan_grasps(scene_density(before), box, GraspConfig(), top_k=args.candidates)
    plan_s = time.perf_counter() - t0
    dicts, cfg, still = [g.to_dict() for g in grasps], ExecuteConfig(), np.eye(4)
    with SimWorld(spec) as world:
        errors = [reach_error(world, g, still, cfg)[0] for g in dicts]
    reachable = [i for i, e in enumerate(errors) if e <= cfg.reach_tolerance_m]
    order = reachable + [i for i in range(len(dicts)) if i not in reachable]
    tries = []
    for i in order[:5]:
        with SimWorld(spec) as world:
            ex = execute_move(world, obj, dicts[i], still, cfg)
            error = placement_error(ex.transform, still, world, obj) if ex.success else None
        tries.append({"planner_rank": i, **ex.to_dict(), "placement_error": error})
        if ex.success:
            break
    row = {"object": obj, "grasps": len(dicts), "reachable": len(reachable)}
    row |= {"plan_s": round(plan_s, 2), "tries": tries}
    row |= {"top1": bool(tries) and tries[0]["success"], "top5": any(t["success"] for t in tries)}
    print(
        f"held-out {scene_dir.name:13s} {obj:20s} grasps {len(dicts)}  reachable "
        f"{len(reachable)}  top1 {row['top1']}  top5 {row['top5']}  plan {plan_s:.1f} s  "
        f"{tries[-1]['cause'] if tries and not tries[-1]['success'] else ''}",
        flush=True,
    )
    return row


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, default=Path("outputs/bench_grasp"))
    parser.add_argument("--views", type=int, default=6)
    parser.add_argument("--scenes", nargs="+", default=[f"pick_place_{k}" for k in range(1, 5)])
    parser.add_argument(
        "--candidates",
        type=int,
        default=20,
        help="grasps kept from the planner, best first (the arm tries up to 5 of them)",
    )
    parser.add_argument(
        "--no-reach-check",
        action="store_true",
        help="try the planner's top 5 in its order (no kinematic check of the arm's reach)",
    )
    parser.add_argument(
        "--bench",
        type=Path,
        default=Path("outputs/bench_standard"),
        help="a neo bench run with --keep-versions: pre scans, NEO's moves, the assembly store",
    )
    parser.add_argument(
        "--data",
        type=Path,
        default=None,
        help="the NEO-Sim suite that run used (its --data; default: the scenes it simulated)",
    )
    parser.add_argument(
        "--figure",
        type=Path,
        default=Path("benchmarks/figures/grasp_and_act.png"),
        help="where the figure goes (default: the committed one; a path under --out leaves "
        "it alone)",
    )
    args = parser.parse_args()
    if args.candidates < 1:
        parser.error("--candidates must be >= 1")
    print("command: python " + " ".join(shlex.quote(a) for a in sys.argv))
    print(f"machine: {platform.machine()}, {platform.system()}, {time.strftime('%Y-%m-%d %H:%M')}")
    bench = RunFolder(args.bench, args.data)
    # every input exists before the first plan (a missing one is one clear error, not a crash
    # after minutes)
    try:
        moves = {name: bench.kept(name, "neo") for name in args.scenes}
    except NeoError as e:
        parser.error(str(e))
    store = bench.version("assembly", "neo")
    if not store.is_dir():
        print(f"no assembly chain in {args.bench} ({store}): its four steps are left out")
    args.out.mkdir(parents=True, exist_ok=True)
    results = {}
    for name in args.scenes:
        before = load_scene(bench.trained(name, "pre"))
        predicted = load_scene(moves[name])
        results[name] = run_object(name, bench.scene_data(name), 1, before, predicted, args)
    heldout = []
    for name in args.scenes:
        scene_dir = bench.scene_data(name)
        meta = json.loads((scene_dir / "scene.json").read_text())
        if "panda" not in meta["spec"]["setup"]["robot_urdf"]:  # KUKA: no gripper
            continue
        before = load_scene(bench.trained(name, "pre"))
        moved = meta["actions"][0]["object"]
        for obj in [o["name"] for o in meta["spec"]["objects"] if o["name"] != moved]:
            heldout.append({"scene": name, **put_back(scene_dir, obj, before, args)})
    for k in range(1, 5):
        if not (store / f"step_{k}").is_dir():
            break
        before, predicted = load_scene(store / f"step_{k - 1}"), load_scene(store / f"step_{k}")
        name = f"assembly_step_{k}"
        results[name] = run_object(name, bench.scene_data("assembly"), k, before, predicted, args)
    rows = [r["neo"].pop("figure") for r in results.values() if "figure" in r.get("neo", {})]
    if rows:  # one row per object: grasps tried | predicted | executed
        width = max(r.shape[1] for r in rows)
        rows = [np.pad(r, ((0, 0), (0, width - r.shape[1]), (0, 0))) for r in rows]
        write_png(args.figure, np.concatenate(rows, axis=0))
    record = {**results, "held-out": heldout}
    (args.out / "results.json").write_text(json.dumps(record, indent=1, default=str))
    fair = [r for r in heldout if r["reachable"]]
    print(
        f"held-out (pick, shake, put back; objects with a reachable grasp): top-1 "
        f"{sum(r['top1'] for r in fair)}/{len(fair)}, top-5 {sum(r['top5'] for r in fair)}/"
        f"{len(fair)}; out of reach: {[r['object'] for r in heldout if not r['reachable']]}"
    )
    # a scene that cannot be executed (the KUKA setup) counts for no planner
    executable = [
        r
        for r in results.values()
        if not any("error" in v for v in r.values() if isinstance(v, dict))
    ]
    for label in ("neo", "truth geometry"):
        rows = [r[label] for r in executable]
        print(
            f"{label}: top-1 {sum(r['top1'] for r in rows)}/{len(rows)}, "
            f"top-5 {sum(r['top5'] for r in rows)}/{len(rows)}, "
            f"plan {np.mean([r['plan_s'] for r in rows]):.1f} s"
        )


if __name__ == "__main__":
    main()
