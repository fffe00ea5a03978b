"""What rays meet outside the scene box: the background, or the room around the box.

A background is a constant colour, an environment map of the ray direction, or a
:class:`~neoedit.fields.room.RoomField`. The renderers composite the box's segment of each
ray and then :func:`outside_light` around it: a room's light in front of the box (and the
fraction of the box it lets through), and the light from behind the box.

The room is sampled along each ray on a warped distance ``g(t)``: linear up to ``t_b`` (the
far side of the ball around the box seen from the ray's origin), then linear in disparity
to the far plane (``g = 2 t_b - t_b^2 / t``, continuous with a continuous slope): about half
the samples near the table, half for the room. The sphere around the box (radius
``start_radius`` half box diagonals, holding the box) is cut out of that domain, so the room
never answers inside the box. Two passes, as the box's own sampler:
density-only samples spread evenly, then samples drawn where they found matter.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from neoedit.fields.background import Background, background_colors
from neoedit.fields.room import RoomField
from neoedit.rendering.intervals import RayIntervals
from neoedit.rendering.light_memo import MEMO, RoomLightEntry, ray_key
from neoedit.rendering.samplers import pdf_edges, uniform_edges
from neoedit.rendering.volume import distortion_loss, render_weights


def warp(t: torch.Tensor, t_b: torch.Tensor) -> torch.Tensor:
    """Ray distance t -> sampling coordinate g (``t_b`` broadcast)."""
    return torch.where(t <= t_b, t, 2.0 * t_b - t_b * t_b / t.clamp_min(1e-9))


def unwarp(g: torch.Tensor, t_b: torch.Tensor) -> torch.Tensor:
    """Inverse of :func:`warp` for g < 2 t_b."""
    return torch.where(g <= t_b, g, t_b * t_b / (2.0 * t_b - g).clamp_min(1e-9))


@dataclass
class RoomMoments:
    """What the distortion loss needs of the room's samples on each ray to weigh them
    against the box's: the summed weights (N,) in front of and behind the box, those
    weights' sums times the samples' positions x (N,), and how a ray distance t maps to x
    (``x = (warp(t, t_b) - g0) / span``, all (N,1): the warped distance, 0 to 1 over the ray);
    ``weight`` scales the terms (:attr:`~neoedit.fields.room.RoomConfig.joint_distortion`)."""

    front_w: torch.Tensor
    front_wx: torch.Tensor
    back_w: torch.Tensor
    back_wx: torch.Tensor
    t_b: torch.Tensor
    g0: torch.Tensor
    span: torch.Tensor
    weight: float = 1.0

    def box_distortion(
        self, weights: torch.Tensor, t_mid: torch.Tensor, front_trans: torch.Tensor
    ) -> torch.Tensor:
        """(N,) the distortion loss's terms between the box's samples (``weights`` (N,M) of
        the box alone, at ray distances ``t_mid``) and the room's, with each part's weight
        on the whole ray (box: ``front_trans`` times its own; room behind: that times the
        light the box lets through). Every room sample in front lies before every box
        sample and every one behind lies after, so ``sum_ij w_i w_j |x_i - x_j|`` splits
        into sums of weights and of weights times positions."""
        x = (warp(t_mid, self.t_b) - self.g0) / self.span
        a, ax = weights.sum(-1), (weights * x).sum(-1)
        front = self.front_w * ax - a * self.front_wx
        back = (1.0 - a) * front_trans * (a * self.back_wx - self.back_w * ax)
        return 2.0 * self.weight * front_trans * (front + back)


@dataclass
class OutsideLight:
    """What lies outside the box's segment of rays: the premultiplied colour (N,3) in front
    of the box and the fraction (N,) of the box it lets through, the colour (N,3) or (3,)
    arriving from behind the box, and, for a room in training, its distortion loss (N,) and
    the :class:`RoomMoments` that couple it to the box's."""

    front_rgb: torch.Tensor | float
    front_trans: torch.Tensor | float
    back_rgb: torch.Tensor
    distortion: torch.Tensor | None = None
    moments: RoomMoments | None = None

    def around(self, box_rgb: torch.Tensor) -> torch.Tensor:
        """Whole-ray colours (N,3): the light in front composited over ``box_rgb`` (the box's
        segment already composited over :attr:`back_rgb`)."""
        if isinstance(self.front_trans, torch.Tensor):
            return self.front_rgb + self.front_trans[:, None] * box_rgb
        return box_rgb


def ray_sphere(
    origins: torch.Tensor, directions: torch.Tensor, center: torch.Tensor, radius: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """Entry and exit distances (N,) of rays (unit directions) with a sphere; exit < entry
    means no hit."""
    oc = origins - center
    b = (oc * directions).sum(-1)
    disc = b * b - ((oc * oc).sum(-1) - radius * radius)
    root = disc.clamp_min(0.0).sqrt()
    miss = disc < 0
    return torch.where(miss, torch.ones_like(b), -b - root), torch.where(
        miss, torch.zeros_like(b), -b + root
    )


def warp_slope(t: torch.Tensor, t_b: torch.Tensor) -> torch.Tensor:
    """dt/dg at ray distance t: a bin's width in g times this is its width in metres
    (taken at the bin's midpoint: far bins, hundreds of metres long, are measured short)."""
    return torch.where(t <= t_b, torch.ones_like(t), (t / t_b) ** 2)


def room_domain(
    room: RoomField, origins: torch.Tensor, directions: torch.Tensor, near_m: float
) -> tuple[RayIntervals, torch.Tensor, torch.Tensor]:
    """The room's part of each ray in warped coordinates (the interval in front of the
    room's inner sphere, the one behind it), the warp's t_b (N,1), and the g (N,) where the
    sphere starts (the far end for rays that miss it)."""
    t_b = ((origins - room.center).norm(dim=-1) + room.radius)[:, None]
    far = t_b[:, 0] + room.cfg.far_factor * room.radius
    near = torch.full_like(far, max(near_m, 0.0))
    # the room is everything beyond the sphere of radius start_radius * r around the box
    # centre (which holds the box): rays are cut at that sphere, not at the box
    t_in, t_out = ray_sphere(origins, directions, room.center, room.cfg.start_radius * room.radius)
    hit = (t_out > t_in) & (t_out > near)
    t_in = torch.where(hit, t_in.clamp(near, far), far)
    t_out = torch.where(hit, t_out.clamp(near, far), far)
    g = warp(torch.stack([near, t_in, t_out, far], -1), t_b)
    return RayIntervals(g[:, [0, 2]], g[:, [1, 3]]), t_b, g[:, 1]


VISIBLE_WEIGHT = 1e-4
"""Without gradients, the room's colour is computed only where a sample's weight exceeds
this (what no render can show is skipped)."""


def _room_samples(room, origins, d, intervals, t_b, g_box, edges, density_only=False):
    """Bins ``edges`` (N, M+1) of the room domain -> sigma (N,M), rgb (N,M,3) (None when
    ``density_only``), widths (N,M) [m] and the bins' warped coordinates (N,M)."""
    n, m = edges.shape[0], edges.shape[1] - 1
    g_mid = intervals.domain_to_t(0.5 * (edges[:, 1:] + edges[:, :-1]))
    t_mid = unwarp(g_mid, t_b)
    deltas = (edges[:, 1:] - edges[:, :-1]) * warp_slope(t_mid, t_b)  # [m], at the midpoint
    points = (origins[:, None, :] + t_mid[..., None] * d[:, None, :]).reshape(-1, 3)
    if density_only:
        return room.density_and_features(points)[0].reshape(n, m), None, deltas, g_mid
    dirs = d[:, None, :].expand(n, m, 3).reshape(-1, 3)
    if torch.is_grad_enabled():
        sigma, rgb = room.query(points, dirs)
        return sigma.reshape(n, m), rgb.reshape(n, m, 3), deltas, g_mid
    sigma, geo = room.density_and_features(points)
    sigma = sigma.reshape(n, m)
    visible = _split_weights(sigma * deltas, g_mid < g_box[:, None]).sum(0) > VISIBLE_WEIGHT
    visible = visible.reshape(-1)
    rgb = torch.zeros(n * m, 3, dtype=geo.dtype, device=geo.device)
    rgb[visible] = room.color(geo[visible], dirs[visible])
    return sigma, rgb.reshape(n, m, 3), deltas, g_mid


def _split_weights(tau: torch.Tensor, front: torch.Tensor) -> torch.Tensor:
    """(2, N, M) volume-rendering weights of optical depths ``tau`` (N,M): of the samples in
    ``front`` of the box, and of those behind it (each with its own transmittance)."""
    ones = torch.ones_like(tau)
    w_front = render_weights(tau * front, ones) * front
    w_back = render_weights(tau * ~front, ones) * ~front
    return torch.stack([w_front, w_back])


def room_light(
    room: RoomField,
    origins: torch.Tensor,
    directions: torch.Tensor,
    near_m: float,
    jitter: bool = False,
    generator: torch.Generator | None = None,
) -> OutsideLight:
    """The room's light around the box on rays (origins, directions (N,3)) starting at
    ``near_m``; differentiable in the room's answers at the rendered samples.

    The room's density is per metre. Measured against density per unit of warped distance
    (exact bin widths, a room transparent at the start): that variant left the label-free
    teacher no support plane on beer_can (10 % of the surface points on the floor, 15 %
    needed), this one found the can (benchmarks/RESULTS.md)."""
    d = directions / directions.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    intervals, t_b, g_box = room_domain(room, origins, d, near_m)
    total = intervals.total
    edges = uniform_edges(total, room.cfg.n_coarse_samples, jitter, generator)
    with torch.no_grad():
        sigma, _, deltas, _ = _room_samples(room, origins, d, intervals, t_b, g_box, edges, True)
        weights = render_weights(sigma, deltas)
    fine = pdf_edges(edges, weights, room.cfg.n_samples, jitter, generator)
    fine[:, 0], fine[:, -1] = 0.0, total  # the whole domain, jittered or not
    sigma, rgb, deltas, g_mid = _room_samples(room, origins, d, intervals, t_b, g_box, fine)
    front = g_mid < g_box[:, None]
    tau_front, tau_back = sigma * deltas * front, sigma * deltas * ~front
    w_front, w_back = _split_weights(sigma * deltas, front)
    beyond = torch.exp(-tau_back.sum(-1))
    back_rgb = (w_back[..., None] * rgb).sum(1) + beyond[:, None] * room.environment(d)
    distortion, moments = None, None
    if torch.is_grad_enabled():
        scale = total.clamp_min(1e-9)[:, None]
        w_all = render_weights(sigma, deltas)
        distortion = distortion_loss(w_all, fine[:, :-1] / scale, fine[:, 1:] / scale)
        if room.cfg.joint_distortion > 0:
            moments = _moments(w_front, w_back, g_mid, intervals, t_b, room.cfg.joint_distortion)
    return OutsideLight(
        (w_front[..., None] * rgb).sum(1),
        torch.exp(-tau_front.sum(-1)),
        back_rgb,
        distortion,
        moments,
    )


def _moments(w_front, w_back, g_mid, intervals: RayIntervals, t_b, weight) -> RoomMoments:
    """The room's side of :meth:`RoomMoments.box_distortion` (its result times ``weight``)."""
    g0 = intervals.starts[:, :1]
    span = (intervals.ends[:, -1:] - g0).clamp_min(1e-9)
    x = (g_mid - g0) / span
    return RoomMoments(
        w_front.sum(-1), (w_front * x).sum(-1), w_back.sum(-1), (w_back * x).sum(-1), t_b, g0, span,
        weight,
    )  # fmt: skip


def outside_light(
    background: Background,
    origins: torch.Tensor,
    directions: torch.Tensor,
    near_m: float,
    jitter: bool = False,
    generator: torch.Generator | None = None,
    opaque: torch.Tensor | None = None,
) -> OutsideLight:
    """What ``background`` adds around the box's segment of rays: a room's light in front of
    and behind the box; for a colour or an environment map, the colour behind it.

    ``opaque`` (N,) bool, without gradients: rays the box stops (a renderer's transmittance
    at its stopping threshold): what lies behind the box cannot show on them, so the room
    is not sampled on those that also have no room in front of the box (a camera inside the
    room's inner sphere, as in every capture walked around a table); their light from
    behind is taken as black, an error of at most the threshold times the room's colour.

    A room this render does not train (no gradients, or frozen weights) and no ``jitter``
    give the same light every time: its light on a chunk of rays is kept for the next render
    of those rays (:mod:`~neoedit.rendering.light_memo`)."""
    if isinstance(background, RoomField):
        if jitter or _trains(background):
            return room_light(background, origins, directions, near_m, jitter, generator)
        with torch.no_grad():  # the room's light is a constant here, even in an edit's loss
            return _room_light_where_seen(background, origins, directions, near_m, opaque)
    return OutsideLight(0.0, 1.0, background_colors(background, origins, directions))


def _trains(room: RoomField) -> bool:
    """Whether this render may train the room (gradients on and its weights want them)."""
    return torch.is_grad_enabled() and any(p.requires_grad for p in room.parameters())


def _room_light_where_seen(
    room: RoomField,
    origins: torch.Tensor,
    directions: torch.Tensor,
    near_m: float,
    opaque: torch.Tensor | None,
) -> OutsideLight:
    """:func:`room_light` on the rays where some of the room can show (all of them without
    ``opaque``; see :func:`outside_light`), nothing on the others; what an earlier render
    of the same rays computed is taken from :data:`~neoedit.rendering.light_memo.MEMO`."""
    n = len(origins)
    seen = torch.ones(n, dtype=torch.bool, device=origins.device)
    if opaque is not None:
        d = directions / directions.norm(dim=-1, keepdim=True).clamp_min(1e-12)
        intervals, _, _ = room_domain(room, origins, d, near_m)
        seen = ~(opaque & (intervals.lengths[:, 0] <= 0.0))
    key = ray_key(room.weights_key(), repr(room.cfg), origins, directions, near_m)
    entry = MEMO.lookup(key)
    if entry is None or entry.done.device != origins.device:
        entry = RoomLightEntry.empty(n, origins.device)
    need = seen & ~entry.done
    if bool(need.any()):
        part = room_light(room, origins[need], directions[need], near_m)
        entry.front_rgb[need] = torch.as_tensor(part.front_rgb, dtype=entry.front_rgb.dtype)
        entry.front_trans[need] = torch.as_tensor(part.front_trans, dtype=entry.front_trans.dtype)
        entry.back_rgb[need] = part.back_rgb
        entry.done |= need
        MEMO.store(key, entry)
    if bool(seen.all()):
        return OutsideLight(
            entry.front_rgb.clone(), entry.front_trans.clone(), entry.back_rgb.clone()
        )
    s = seen[:, None]
    return OutsideLight(
        torch.where(s, entry.front_rgb, 0.0),
        torch.where(seen, entry.front_trans, 1.0),
        torch.where(s, entry.back_rgb, 0.0),
    )
