"""Teacher -> student distillation of a radiance field (paper Sec. III-C, eq. 6).

The teacher is any field (a composite of regions: :mod:`neoedit.fields.composed`); the
student is a plain :class:`RadianceField` initialised from the current weights, so the
edited version keeps the structure of its input. Two stages:

1. **field**: per-sample L1 between teacher and student density and colour. Density is
   compared as the opacity of a ``opacity_step_m`` step, 1 - exp(-sigma * step), because
   raw densities span 0 .. 1e4 /m and an L1 on them is dominated by the table's interior;
   colour is weighted by the teacher's opacity (colour in empty space is free). Samples are
   the teacher's PDF samples along the rays plus uniform points in the edit boxes (where
   the student still holds what the teacher no longer has: the object at its old place).
2. **render**: the student's rendered RGB (MSE) and z-depth (L1, where the teacher is
   opaque) against the teacher's renders of the same rays.

Rays come from a :class:`RayPool`: a share ``focus`` of every batch from pixels whose ray
crosses an edit box (scan cameras and the virtual object-centred views), the rest uniform
over the scan's pixels, which holds the rest of the scene where it was.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass

import torch

from neoedit.cameras import Cameras
from neoedit.cameras.rays import CameraTensors, RayBundle
from neoedit.edit.points import box_points
from neoedit.errors import NeoError
from neoedit.fields.background import Background
from neoedit.fields.radiance import Field, RadianceField
from neoedit.geometry import OrientedBox, points_in_boxes
from neoedit.geometry.masks import box_pixels
from neoedit.rendering.occupancy import OccupancyGrid
from neoedit.rendering.renderer import RenderConfig, render_rays, sample_rays
from neoedit.utils.fit import fit
from neoedit.utils.optim import field_param_groups, frozen, make_adam
from neoedit.utils.progress import make_progress


@dataclass
class DistillConfig:
    field_steps: int = 40
    """Stage 1 steps: per-sample density + colour L1 (0: skip the stage)."""
    render_steps: int = 80
    """Stage 2 steps: rendered RGB + depth against the teacher's renders (0: skip)."""
    rays: int = 1024
    """Rays per step."""
    focus: float = 0.75
    """Share of every batch drawn from pixels whose ray crosses an edit box."""
    box_points: int = 4096
    """Stage 1: uniform points per step inside the edit boxes."""
    opacity_step_m: float = 0.005
    """Step length that turns densities into the opacities stage 1 compares."""
    lambda_depth: float = 0.5
    """Weight of the stage-2 z-depth L1 [1/m]."""
    lr: float = 2e-2
    """Learning rate of the student's hash table (fresh Adam, decaying 10x over a stage;
    measured on pick_place_1: In-PSNR 17.9 dB at 1e-2, 18.9 dB at 2e-2, at the same Rest)."""
    mlp_lr_factor: float = 0.0
    """The student's MLPs learn at this fraction of ``lr``; 0 freezes them (the default:
    they serve the whole scene; measured on pick_place_1, 0.1 cost 0.7 dB Rest-PSNR and
    gained nothing in the boxes)."""
    patch_mlp_lr_factor: float = 1.0
    """``mlp_lr_factor`` when the student is a patch: a patch's MLPs answer only inside its
    own boxes, so they can learn the moved object with the table (measured on NEO-Sim
    pick_place_2, the duck: In-PSNR 14.6 dB with them frozen, 18.2 dB at 1.0)."""
    freeze_mlp: bool = False
    """Update only the hash table (Seal-3D's local stage does this)."""
    local_rows: bool = True
    """Each step updates only the table rows read by samples inside the edit boxes. Adam
    moves every row a gradient touches by about the learning rate, however small the
    gradient, so without this the rays that hold the rest of the scene jitter the whole
    table (measured on NEO-Sim pick_place_1: Rest-PSNR -0.7 dB, a blotchy table)."""
    regions_only: bool = False
    """The student already equals the teacher outside the edit boxes (a patch student over
    the teacher's own base field), so only what crosses a box can teach it: every ray of a
    batch is drawn through a box (``focus`` of ``rays`` of them, the same number of useful
    rays as without this) and stage 1 compares only the samples inside the boxes."""
    seed: int = 0

    def check(self, where: str = "--edit.distill") -> None:
        """Refuse settings that would write a version whose student never trained (before
        any work starts)."""
        if not _whole(self.rays, 1):
            raise NeoError(f"{where}.rays must be a whole number >= 1")
        for name in ("field_steps", "render_steps", "box_points"):
            if not _whole(getattr(self, name), 0):
                raise NeoError(f"{where}.{name.replace('_', '-')} must be a whole number >= 0")
        if self.field_steps + self.render_steps < 1:
            raise NeoError(f"{where}: field-steps and render-steps are both 0: nothing would learn")
        numbers = ("focus", "opacity_step_m", "lambda_depth", "lr", "mlp_lr_factor")
        for name in (*numbers, "patch_mlp_lr_factor"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value >= 0):
                raise NeoError(f"{where}.{name.replace('_', '-')} must be a finite number >= 0")
        if self.focus > 1 or self.lr <= 0 or self.opacity_step_m <= 0:
            raise NeoError(f"{where}: focus must be in [0, 1], lr and opacity-step-m > 0")


class RayPool:
    """Rays to distil on: pixels of the scan cameras and of virtual views, with the pixels
    whose ray crosses an edit box kept apart so a batch can focus on them."""

    def __init__(
        self,
        scan: Cameras,
        virtual: Cameras | None,
        boxes: Sequence[OrientedBox],
        device: torch.device | str,
        seed: int = 0,
    ):
        cams = Cameras.concat([scan, virtual]) if virtual is not None and len(virtual) else scan
        self.n_scan = len(scan)
        self.cams = CameraTensors(cams, device)
        self.width, self.height = cams.width, cams.height
        # (P,3) camera, v, u of the pixels whose ray crosses an edit box
        self.focus = torch.as_tensor(box_pixels(cams, list(boxes)), device=device)
        self.device = device
        self.gen = torch.Generator().manual_seed(seed)

    def sample(self, n: int, focus: float) -> RayBundle:
        k = int(round(n * focus)) if len(self.focus) else 0
        pick = self.focus[torch.randint(0, len(self.focus), (k,), generator=self.gen)]
        cam = torch.randint(0, self.n_scan, (n - k,), generator=self.gen)
        v = (torch.rand(n - k, generator=self.gen) * torch.as_tensor(self.height)[cam]).long()
        u = (torch.rand(n - k, generator=self.gen) * torch.as_tensor(self.width)[cam]).long()
        idx = torch.cat([pick, torch.stack([cam, v, u], -1).to(self.device)])
        return self.cams.rays(idx[:, 0], idx[:, 1], idx[:, 2])


def _opacity(sigma: torch.Tensor, step_m: float) -> torch.Tensor:
    return 1.0 - torch.exp(-step_m * sigma)


def field_loss(
    student: Field,
    teacher: Field,
    points: torch.Tensor,
    directions: torch.Tensor,
    step_m: float,
) -> torch.Tensor:
    """Stage 1 (eq. 6, first case): mean |opacity_t - opacity_s| + opacity_t * |c_t - c_s|_1."""
    with torch.no_grad():
        sigma_t, rgb_t = teacher(points, directions)
        alpha_t = _opacity(sigma_t, step_m)
    sigma_s, rgb_s = student(points, directions)
    density = torch.mean(torch.abs(alpha_t - _opacity(sigma_s, step_m)))
    colour = torch.mean(alpha_t[:, None] * torch.abs(rgb_t - rgb_s))
    return density + colour


def render_loss(
    student_out: dict[str, torch.Tensor], teacher_out: dict[str, torch.Tensor], lambda_depth: float
) -> torch.Tensor:
    """Stage 2 (eq. 6, second case): rendered RGB MSE + z-depth L1 where the teacher is
    opaque."""
    loss = torch.mean((student_out["rgb"] - teacher_out["rgb"]) ** 2)
    opaque = teacher_out["accumulation"] > 0.5
    if lambda_depth > 0 and bool(opaque.any()):
        err = torch.abs(student_out["depth_z"] - teacher_out["depth_z"])[opaque]
        loss = loss + lambda_depth * err.mean()
    return loss


def _decay(steps: int, step: int) -> float:
    """10x exponential decay over ``steps``."""
    return 0.1 ** (step / max(steps, 1))


def _trainable_parts(
    student: RadianceField | Sequence[tuple[RadianceField, float]],
    cfg: DistillConfig,
    view: Field | None,
) -> list[tuple[RadianceField, float]]:
    """The student's parts with their MLP rate factors, gradients switched on (the MLPs'
    off where they are frozen)."""
    parts = [(student, cfg.mlp_lr_factor)] if isinstance(student, RadianceField) else list(student)
    if not parts or (len(parts) > 1 and (view is None or cfg.local_rows)):
        raise ValueError("several students need a view holding them and local_rows off")
    for part, factor in parts:
        part.requires_grad_(True)
        if cfg.freeze_mlp or factor == 0:
            for name, p in part.named_parameters():
                p.requires_grad_(name.startswith("encoding."))
    return parts


def _batch(
    cfg: DistillConfig, pool: RayPool, boxes: list[OrientedBox], view: Field | None
) -> tuple[int, float]:
    """(rays per step, share of them drawn through a box)."""
    if not cfg.regions_only:
        return cfg.rays, cfg.focus
    if view is None or not boxes or not len(pool.focus) or cfg.focus <= 0:
        raise ValueError(
            "regions_only needs a patch student (a view holding it), edit boxes and rays "
            "through them"
        )
    return max(1, int(round(cfg.rays * cfg.focus))), 1.0


def distill(
    student: RadianceField | Sequence[tuple[RadianceField, float]],
    student_grid: OccupancyGrid,
    teacher: Field,
    teacher_grid: OccupancyGrid,
    pool: RayPool,
    boxes: Sequence[OrientedBox],
    render_cfg: RenderConfig,
    background: Background,
    cfg: DistillConfig,
    view: Field | None = None,
) -> dict[str, float]:
    """Fit ``student`` (in place) to ``teacher`` in the two stages of eq. 6; returns the
    final smoothed loss of each stage. ``student_grid`` is where the student is sampled in
    stage 2 (it should cover both the teacher's content and the student's old content).
    ``view`` is the field the losses see when ``student`` is a part of it (a patch of a
    :class:`~neoedit.fields.patched.PatchedField`); by default the student itself.
    ``student`` may also be several parts of ``view`` trained together, each given with the
    fraction of ``lr`` its MLPs learn at (0 freezes them); a plain field uses
    ``cfg.mlp_lr_factor``."""
    parts = _trainable_parts(student, cfg, view)
    student = parts[0][0]
    device = student.aabb.device
    seen: Field = student if view is None else view
    gen = torch.Generator().manual_seed(cfg.seed)
    ray_gen = torch.Generator(device=device).manual_seed(cfg.seed)
    boxes = list(boxes)
    rows: list[torch.Tensor] = []  # the current step's row mask (read by the gradient hook)
    n_rays, focus = _batch(cfg, pool, boxes, view)

    def allow(points: torch.Tensor) -> None:
        """Let this step update only the rows read by ``points`` that lie in a box."""
        if not cfg.local_rows:
            return
        u, _ = student.normalize(points[points_in_boxes(points, boxes)].detach())
        rows[:] = [student.encoding.touched_rows(u)[..., None]]

    hook = student.encoding.table.register_hook(lambda g: g * rows[0] if rows else g)

    def stage1(_: int) -> torch.Tensor:
        rays = pool.sample(n_rays, focus)
        with torch.no_grad():
            s = sample_rays(teacher, teacher_grid, rays, render_cfg, (), True, ray_gen)
        n, m = s.t_mid.shape
        keep = (s.deltas.reshape(-1) > 0) & teacher_grid.is_occupied(s.points.reshape(-1, 3))
        if cfg.regions_only:
            keep &= points_in_boxes(s.points.reshape(-1, 3), boxes)
        pts = s.points.reshape(-1, 3)[keep]
        dirs = rays.directions[:, None, :].expand(n, m, 3).reshape(-1, 3)[keep]
        if boxes and cfg.box_points > 0:
            inside = torch.cat(
                [box_points(b, cfg.box_points // len(boxes), 0.0, gen, device) for b in boxes]
            )
            rand_dirs = torch.nn.functional.normalize(
                torch.randn(len(inside), 3, generator=gen).to(device), dim=-1
            )
            pts, dirs = torch.cat([pts, inside]), torch.cat([dirs, rand_dirs])
        allow(pts)
        return field_loss(seen, teacher, pts, dirs, cfg.opacity_step_m)

    def stage2(_: int) -> torch.Tensor:
        rays = pool.sample(n_rays, focus)
        with torch.no_grad():
            target = render_rays(teacher, teacher_grid, rays, render_cfg, background)
        out = render_rays(
            seen, student_grid, rays, render_cfg, background, jitter=True, generator=ray_gen
        )
        pts = rays.origins[:, None, :] + out["t_mid"][..., None] * rays.directions[:, None, :]
        allow(pts.reshape(-1, 3)[out["weights"].reshape(-1) > 0])
        return render_loss(out, target, cfg.lambda_depth)

    losses = {}
    # the background (a room, an environment map) is the parent's: it takes no gradient
    # (its renders build no graph), unless a student holds it
    students = {id(p) for part, _ in parts for p in part.parameters()}
    own = isinstance(background, torch.nn.Module) and any(
        id(p) in students for p in background.parameters()
    )
    with make_progress() as progress, frozen(None if own else background):
        for name, steps, fn in (
            ("field", cfg.field_steps, stage1),
            ("render", cfg.render_steps, stage2),
        ):
            if steps <= 0:
                continue
            groups = [g for part, f in parts for g in field_param_groups(part, cfg.lr, f)]
            optimizer = make_adam(groups, cfg.lr, device)
            task = progress.add_task(f"distil: {name}", total=steps, status="")
            losses[name] = fit(
                optimizer,
                steps,
                fn,
                name,
                lr_scale=functools.partial(_decay, steps),
                bar=(progress, task),
            )
    hook.remove()
    for part, _ in parts:
        part.requires_grad_(False)
    return losses


def _whole(value: object, least: int) -> bool:
    return isinstance(value, int) and not isinstance(value, bool) and value >= least
