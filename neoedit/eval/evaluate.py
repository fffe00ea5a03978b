"""Evaluate a scene against ground-truth views: Full / Out / In regions (paper Sec. V)."""

from __future__ import annotations

import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from neoedit.cameras import Cameras
from neoedit.cameras.rays import CameraTensors
from neoedit.data import SceneData
from neoedit.data.sparse_depth import is_sparse
from neoedit.eval.align import AlignConfig, align_cameras, alignment_summary
from neoedit.eval.metrics import ObjectColours, depth_rmse_m, psnr, reprojection_error, ssim
from neoedit.geometry import OrientedBox
from neoedit.geometry.masks import masks_for_boxes
from neoedit.scene import Scene
from neoedit.utils.io import write_png
from neoedit.utils.progress import track

METRICS = ("psnr", "ssim", "depth_rmse_m", "e_rep")


def eval_cameras(scene: Scene, data: SceneData) -> Cameras:
    """The cameras ``data``'s photos are compared at: the dataset's, except for the scene's
    own scan, whose training refined its poses (its corrected poses; held-out photos keep
    theirs)."""
    scan = scene.meta.scan or {}
    if "pose_corrections" in scan and list(scan.get("file_paths", [])) == list(data.file_paths):
        return scene.scan_cameras()[0]
    return data.cameras


def render_views(
    scene: Scene, data: SceneData, indices: Sequence[int], cameras: Cameras | None = None
) -> list[dict[str, np.ndarray]]:
    """Render the dataset's cameras ``indices`` (or those of ``cameras``) as the scene
    version renders them (its render-time removals included) -> rgb (H,W,3) in [0,1],
    depth_z (H,W) [m], accumulation; by default at :func:`eval_cameras`."""
    device = scene.field.aabb.device
    cams = CameraTensors(eval_cameras(scene, data) if cameras is None else cameras, device)
    out = []
    for i in track(list(indices), "render"):
        r = scene.render_image(cams, int(i), data.height, data.width)
        out.append({k: v.detach().cpu().numpy() for k, v in r.items()})
    return out


def evaluate(
    scene: Scene,
    data: SceneData,
    split: str = "test",
    out_boxes: Sequence[OrientedBox] = (),
    in_boxes: Sequence[OrientedBox] = (),
    image_dir: Path | None = None,
    max_views: int | None = None,
    align: AlignConfig | None = None,
) -> dict[str, Any]:
    """Metrics of ``scene`` rendered at the ``split`` cameras of ``data`` (ground truth);
    ``max_views`` evenly chosen of them when given. Depth RMSE needs dense depth (a
    sensor's, NEO-Sim's): structure-from-motion points are no ground truth (NaN). With
    instance labels, ``objects`` holds each object's mean colour, rendered and true.
    ``align``: each evaluated camera is first fitted to its photo (:mod:`neoedit.eval.align`;
    ``aligned`` then says by how much)."""
    indices = [int(i) for i in data.indices(split)]
    dense_depth = data.depth_m is not None and not is_sparse(data.depth_m)
    if max_views is not None and 0 < max_views < len(indices):
        pick = np.linspace(0, len(indices) - 1, max_views).round().astype(int)
        indices = [indices[k] for k in pick]
    if not indices:
        raise ValueError(f"split '{split}' of {data.root} has no frames")
    cameras, aligned = eval_cameras(scene, data), None
    if align is not None:
        edited = [*out_boxes, *in_boxes]
        cameras, fixes = align_cameras(scene, data, cameras, indices, align, exclude=edited)
        aligned = alignment_summary(fixes, align)
    t0 = time.perf_counter()
    renders = render_views(scene, data, indices, cameras)
    seconds_per_view = (time.perf_counter() - t0) / len(indices)
    regions: dict[str, list[np.ndarray | None]] = {"full": [None] * len(indices)}
    if out_boxes:
        regions["out"] = [masks_for_boxes(cameras, i, list(out_boxes)) for i in indices]
    if in_boxes:
        regions["in"] = [masks_for_boxes(cameras, i, list(in_boxes)) for i in indices]
    if out_boxes or in_boxes:  # "rest": outside every edited box
        edited = list(out_boxes) + list(in_boxes)
        regions["rest"] = [~masks_for_boxes(cameras, i, edited) for i in indices]
    per_region: dict[str, dict[str, list[float]]] = {r: {m: [] for m in METRICS} for r in regions}
    ids = data.instance_ids
    colours = ObjectColours(data.instance_names) if ids is not None else None
    for k, i in enumerate(indices):
        gt = data.images[i].astype(np.float32) / 255.0
        pred = renders[k]["rgb"].clip(0.0, 1.0)
        if colours is not None and ids is not None:
            colours.add(pred, gt, ids[i])
        nxt = (k + 1) % len(indices)
        for region, masks in regions.items():
            mask = masks[k]
            m = per_region[region]
            m["psnr"].append(psnr(pred, gt, mask))
            m["ssim"].append(ssim(pred, gt, mask))
            m["depth_rmse_m"].append(
                depth_rmse_m(renders[k]["depth_z"], data.depth_m[i], mask)
                if dense_depth and data.depth_m is not None
                else float("nan")
            )
            if len(indices) > 1:
                m["e_rep"].append(
                    reprojection_error(
                        pred,
                        renders[k]["depth_z"],
                        renders[nxt]["rgb"].clip(0, 1),
                        cameras,
                        i,
                        indices[nxt],
                        mask,
                    )[0]
                )
        if image_dir is not None:
            side = np.concatenate([pred, gt], axis=1)
            write_png(
                image_dir / f"{Path(data.file_paths[i]).stem}.png",
                (side * 255).round().astype(np.uint8),
            )
    result: dict[str, Any] = {
        region: {m: _nanmean(v) for m, v in values.items()} for region, values in per_region.items()
    }
    if colours is not None:
        result["objects"] = colours.result()
    if aligned is not None:
        result["aligned"] = aligned
    result["n_views"] = len(indices)
    result["split"] = split
    result["render_seconds_per_view"] = round(seconds_per_view, 3)
    return result


def _nanmean(values: list[float]) -> float | None:
    arr = np.asarray(values, dtype=np.float64)
    arr = arr[np.isfinite(arr)]
    return round(float(arr.mean()), 5) if len(arr) else None
