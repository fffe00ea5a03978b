"""The support around a box, on a field with a known dark patch on a plane: the shadow an
object casts is found around its footprint and joins the removal; a removal's footprint is
measured against the ring of support around it."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from torch import nn

from neoedit.cameras import Cameras
from neoedit.cameras.cameras import look_at
from neoedit.edit.shadow import ShadowConfig, find_shadow, find_shadows
from neoedit.errors import NeoError
from neoedit.eval.footprint import FootprintContrast, footprint_contrast
from neoedit.geometry import OrientedBox
from neoedit.rendering.renderer import RenderConfig

OBJECT = OrientedBox((0.0, 0.0, 0.05), (0.06, 0.04, 0.1), 30.0)


class Table(nn.Module):
    """An opaque table top at z = 0 (grey 0.6), darker (0.3) where ``shadow(x, y)``."""

    def __init__(self, shadow):
        super().__init__()
        self.shadow = shadow
        self.register_buffer("aabb", torch.tensor([[-0.5, -0.5, -0.1], [0.5, 0.5, 0.4]]))

    def density(self, points):
        return torch.where(points[:, 2] < 0.0, 2000.0, 0.0)

    def forward(self, points, directions):
        dark = self.shadow(points[:, 0], points[:, 1])
        grey = torch.where(dark, 0.3, 0.6)
        return self.density(points), grey[:, None].expand(-1, 3)


def test_a_shadow_beside_the_footprint_is_found_and_held_by_the_slab():
    # a 4 cm x 6 cm dark patch touching the footprint's +x side in the world frame
    def shadow(x, y):
        return (x > 0.0) & (x < 0.07) & (y.abs() < 0.03)

    found = find_shadow(Table(shadow), OBJECT, ShadowConfig())
    assert found is not None
    slab = found.slab
    assert slab.yaw_deg == OBJECT.yaw_deg
    xs, ys = np.meshgrid(np.linspace(0.005, 0.065, 13), np.linspace(-0.025, 0.025, 11))
    above = 0.006  # just over the table, in the slab
    patch = np.stack([xs.ravel(), ys.ravel(), np.full(xs.size, above)], 1)
    assert slab.contains(patch, margin_m=1e-6).all()  # every shadowed cell is under the slab
    foot = OBJECT.corners()[:4] * [1, 1, 0] + [0, 0, above]
    assert slab.contains(foot, margin_m=1e-6).all()  # and the footprint
    far = np.array([[-0.12, 0.0, above], [0.0, -0.12, above], [0.15, 0.0, above]])
    assert not slab.contains(far).any()  # not the lit table around it
    bottom = slab.center_m[2] - slab.size_m[2] / 2
    assert 0.0 < bottom < 0.005 and slab.size_m[2] < 0.02  # thin, and the table is not cut


class Painted(Table):
    """The same table, its colour (N,3) painted by ``paint(x, y)``."""

    def __init__(self, paint):
        super().__init__(None)
        self.paint = paint

    def forward(self, points, directions):
        return self.density(points), self.paint(points[:, 0], points[:, 1])


def _wood(x, y, shadow=None):
    """A grey table with 3 mm stripes 6 % lighter and darker (a grain as dark, cell by
    cell, as a soft shadow), darkened 12 % where ``shadow``."""
    grey = 0.6 * (1 + 0.06 * torch.sign(torch.sin(x * 2 * np.pi / 0.006)))
    if shadow is not None:
        grey = torch.where(shadow(x, y), 0.88 * grey, grey)
    return grey[:, None].expand(-1, 3)


def test_the_shadows_ratio_is_measured_and_laid_around_a_target_translated():
    def shadow(x, y):
        return (x > 0.0) & (x < 0.07) & (y.abs() < 0.03)

    found = find_shadow(Table(shadow), OBJECT, ShadowConfig())
    assert found is not None
    np.testing.assert_allclose(found.ratio.min(), 0.5, atol=0.03)  # 0.3 on 0.6
    gx, gy = np.meshgrid(found.axis, found.axis, indexing="ij")
    far = np.hypot(gx, gy) > 0.1
    assert (found.ratio[far] == 1.0).all()  # the lit table is left as it is
    assert abs(found.support_z_m) < 1e-3  # the table top, under the box's bottom
    motion = np.eye(4)
    motion[:3, :3] = [[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]  # 90 deg of yaw
    motion[:3, 3] = (0.2, -0.1, 0.03)  # onto a shelf 3 cm higher
    slab, ratio = found.shade_at(motion)
    assert np.allclose(slab.center_m, (0.2, -0.1, 0.03), atol=1e-3)  # on the new support
    assert slab.yaw_deg == OBJECT.yaw_deg  # the light did not turn with the object
    assert np.isclose(slab.size_m[0], found.axis[-1] - found.axis[0])
    assert ratio.shape == found.ratio.shape and ratio.dtype == np.float32


def test_a_soft_shadow_is_told_from_a_grain_as_dark_and_a_base_of_another_hue_is_not_one():
    def beside(x, y):
        return (x > 0.0) & (x < 0.08) & (y.abs() < 0.035)

    assert find_shadow(Painted(_wood), OBJECT, ShadowConfig()) is None
    soft = find_shadow(Painted(lambda x, y: _wood(x, y, beside)), OBJECT, ShadowConfig())
    assert soft is not None and 0.8 < soft.ratio.min() < 0.95

    def red_base(x, y):  # an object's red base seen inside its box, on the table's plane
        rgb = _wood(x, y).clone()
        rgb[(x**2 + y**2) < 0.015**2] = torch.tensor([0.5, 0.05, 0.05])
        return rgb

    assert find_shadow(Painted(red_base), OBJECT, ShadowConfig()) is None


def test_no_shadow_is_looked_for_on_a_checkerboard():
    """A checker's dark squares touching the footprint are as dark as any shadow and of
    the same hue: on a support that textured the search finds nothing, shadow or not."""

    def checker(x, y, shadow=None):
        odd = (torch.floor(x / 0.025) + torch.floor(y / 0.025)) % 2 == 1
        grey = torch.where(odd, 0.25, 0.6)
        if shadow is not None:
            grey = torch.where(shadow(x, y), 0.5 * grey, grey)
        return grey[:, None].expand(-1, 3)

    def beside(x, y):
        return (x > 0.0) & (x < 0.08) & (y.abs() < 0.035)

    assert find_shadow(Painted(checker), OBJECT, ShadowConfig()) is None
    shaded = Painted(lambda x, y: checker(x, y, beside))
    assert find_shadow(shaded, OBJECT, ShadowConfig()) is None
    assert find_shadow(shaded, OBJECT, ShadowConfig(max_texture=1.0)) is not None


def test_no_shadow_no_slab_and_a_dark_spot_apart_is_not_a_shadow():
    assert (
        find_shadow(
            Table(lambda x, y: torch.zeros_like(x, dtype=torch.bool)), OBJECT, ShadowConfig()
        )
        is None
    )

    def apart(x, y):  # dark, but not touching the footprint
        return ((x - 0.09) ** 2 + y**2) < 0.01**2

    assert find_shadow(Table(apart), OBJECT, ShadowConfig()) is None
    off = ShadowConfig(enabled=False)
    assert find_shadows(Table(lambda x, y: x > 0), [OBJECT], off) == [None]


@pytest.mark.parametrize(
    "field,value",
    [
        ("darker", 1.0),
        ("cell_m", 0.0),
        ("reach", -1.0),
        ("smooth_cells", -1.0),
        ("max_texture", 2.0),
    ],
)
def test_bad_shadow_settings_are_refused(field, value):
    with pytest.raises(NeoError, match=field.replace("_", "-")):
        ShadowConfig(**{field: value}).check()


def _ring_of_cameras(n: int = 8) -> Cameras:
    eyes = [(0.4 * np.cos(a), 0.4 * np.sin(a), 0.4) for a in np.linspace(0, 2 * np.pi, n, False)]
    c2w = np.stack([look_at(np.array(e), np.zeros(3)) for e in eyes])
    return Cameras.shared(c2w, 100.0, 100.0, 64.0, 48.0, 128, 96)


def _contrast(field: Table) -> FootprintContrast:
    black = torch.zeros(3)
    render = RenderConfig(n_coarse_samples=256, n_samples=64)
    return footprint_contrast(field, None, black, render, _ring_of_cameras(), OBJECT)


def test_a_footprint_darker_than_its_ring_is_measured_and_a_seamless_one_is_not():
    def disc(x, y):  # a dark disc where the object stood (its box is 6 x 4 cm)
        return (x**2 + y**2) < 0.035**2

    stained = _contrast(Table(disc))
    assert stained.views == 8
    np.testing.assert_allclose(stained.footprint_rgb, [76.5] * 3, atol=1.0)
    np.testing.assert_allclose(stained.ring_rgb, [153.0] * 3, atol=1.0)
    assert abs(stained.delta - 76.5) < 2.0
    assert stained.footprint_opacity > 0.99 and stained.ring_opacity > 0.99
    assert _contrast(Table(lambda x, y: torch.zeros_like(x, dtype=torch.bool))).delta < 1.0

    def wide(x, y):
        return (x**2 + y**2) < 0.05**2

    class Hole(Table):  # a 1 cm table missing under the object: those rays see the background
        def density(self, points):
            top = (points[:, 2] < 0.0) & (points[:, 2] > -0.01)
            return torch.where(top & ~wide(points[:, 0], points[:, 1]), 2000.0, 0.0)

    hole = _contrast(Hole(wide))
    assert hole.footprint_opacity < 0.01 and hole.ring_opacity > 0.99
    assert hole.footprint_rgb == [0.0, 0.0, 0.0] and hole.delta > 150


def test_a_footprint_ring_leaves_out_what_lies_under_excluded_boxes():
    """A move's footprint is measured without the ring points under its target (the moved
    object would count as 'the support around it'); a ring all under them is refused."""
    black, render = torch.zeros(3), RenderConfig(n_coarse_samples=256, n_samples=64)

    def disc(x, y):  # the footprint's stain, as in the test above
        return (x**2 + y**2) < 0.035**2

    def measure(field: Table, exclude=()) -> float:
        cams = _ring_of_cameras()
        return footprint_contrast(field, None, black, render, cams, OBJECT, exclude=exclude).delta

    # most of the ring dark (a moved object standing beside its old place, seen as support)
    crowded = Table(lambda x, y: disc(x, y) | (x > -0.02))
    target = OrientedBox((0.09, 0.0, 0.05), (0.22, 0.4, 0.1), 0.0)  # over that part
    assert measure(crowded) < 10.0  # the stain hidden: the "ring" is as dark as it
    assert measure(crowded, [target]) == pytest.approx(measure(Table(disc)), abs=2.0)
    everywhere = OrientedBox((0.0, 0.0, 0.05), (1.0, 1.0, 0.1), 0.0)
    with pytest.raises(NeoError, match="ring around the footprint lies under"):
        measure(Table(disc), [everywhere])
