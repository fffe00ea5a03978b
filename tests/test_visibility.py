"""What the scan saw: the visibility test and the box helpers of a removal."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from neoedit.cameras import Cameras, look_at
from neoedit.edit.masks import grown_box, grown_box_clear_of
from neoedit.edit.visibility import seen_by_cameras
from neoedit.fields.patched import inside_box
from neoedit.geometry import OrientedBox

OBJECT = OrientedBox((0.0, 0.0, 0.05), (0.1, 0.1, 0.1), 0.0)


class BoxDensity(torch.nn.Module):
    """An opaque box (density 1e4 / m inside, 0 elsewhere)."""

    def density(self, points: torch.Tensor) -> torch.Tensor:
        return inside_box(points, OBJECT).float() * 1e4


def cameras_at(eyes: list[tuple[float, float, float]]) -> Cameras:
    poses = np.stack([look_at(np.array(e), np.zeros(3)) for e in eyes])
    n = len(eyes)
    return Cameras(
        poses,
        np.full(n, 300.0),
        np.full(n, 300.0),
        np.full(n, 160.0),
        np.full(n, 120.0),
        np.full(n, 320),
        np.full(n, 240),
    )


def test_points_hidden_behind_an_object_are_unseen_until_a_camera_looks_from_behind():
    behind = torch.tensor([[0.12, 0.0, 0.02]])  # on the +x side of the object
    under = torch.tensor([[0.0, 0.0, 0.0]])  # under the object: no camera sees it
    points = torch.cat([behind, under])
    front = cameras_at([(-0.8, 0.0, 0.3)])  # looks at it through the object
    back = cameras_at([(0.8, 0.0, 0.3)])
    field = BoxDensity()
    assert seen_by_cameras(field, None, points, front, near_m=0.05).tolist() == [False, False]
    both = Cameras(
        *(
            np.concatenate([getattr(front, f), getattr(back, f)])
            for f in ("camera_to_world", "fx", "fy", "cx", "cy", "width", "height")
        )
    )
    assert seen_by_cameras(field, None, points, both, near_m=0.05).tolist() == [True, False]
    # a point outside every image is not seen either
    assert not seen_by_cameras(field, None, torch.tensor([[0.0, 3.0, 0.0]]), back, 0.05)[0]


def test_margin_stops_short_of_a_neighbour_and_ignores_stray_points():
    box = OrientedBox((0.0, 0.0, 0.05), (0.1, 0.06, 0.1), 30.0)
    rot = box.rotation
    # a neighbour 6 mm beyond the +x face, a stray point 4 mm beyond the -y face
    neighbour = np.array([[0.056, y, z] for y in (-0.01, 0.0, 0.01) for z in (0.04, 0.06)])
    stray = np.array([[0.0, -0.034, 0.05]])
    pts = np.vstack([neighbour, stray]) @ rot.T + np.array(box.center_m)
    clear = grown_box_clear_of(box, 0.01, pts, gap_m=0.003)
    free = grown_box(box, 0.01)
    assert not clear.contains(neighbour @ rot.T + np.array(box.center_m)).any()
    assert clear.contains(box.corners(), margin_m=1e-9).all()  # never smaller than the box
    lo_local = clear.world_to_local(clear.corners()).min(0)
    hi_local = box.world_to_local(clear.corners()).max(0)
    assert abs(hi_local[0] - (0.05 + 0.003)) < 1e-6  # +x grew 3 mm: 6 mm away minus the gap
    assert (
        abs(box.world_to_local(clear.corners()).min(0)[1] - (-0.03 - 0.01)) < 1e-6
    )  # stray ignored
    assert clear.size_m[2] == free.size_m[2] and lo_local[2] < 0
    assert grown_box_clear_of(box, 0.01, np.zeros((0, 3))) == free


def test_a_box_reaching_under_the_table_is_seated_on_it():
    from types import SimpleNamespace

    from neoedit.edit.remove import seated_on_support

    gen = np.random.default_rng(0)
    table = np.column_stack([gen.uniform(-0.3, 0.3, (4000, 2)), gen.normal(0.0, 0.001, 4000)])
    scene = SimpleNamespace(surface_points_m=torch.as_tensor(table, dtype=torch.float32))
    low = OrientedBox((0.0, 0.0, 0.0075), (0.1, 0.04, 0.025), 20.0)  # bottom 5 mm under z=0
    seated = seated_on_support(scene, low)
    assert abs((seated.center_m[2] - seated.size_m[2] / 2) - 0.0) < 0.001
    assert abs((seated.center_m[2] + seated.size_m[2] / 2) - 0.02) < 1e-9  # top kept
    # a box that stops short of the table is lowered onto it (else the object's base stays)
    high = OrientedBox((0.0, 0.0, 0.022), (0.1, 0.04, 0.02), 20.0)  # bottom 12 mm above
    lowered = seated_on_support(scene, high)
    assert abs(lowered.center_m[2] - lowered.size_m[2] / 2) < 0.001
    assert abs((lowered.center_m[2] + lowered.size_m[2] / 2) - 0.032) < 1e-9  # top kept
    above = OrientedBox((0.0, 0.0, 0.06), (0.1, 0.04, 0.02), 20.0)  # 5 cm up: another support
    assert seated_on_support(scene, above) == above
    assert seated_on_support(SimpleNamespace(surface_points_m=None), low) == low


def test_support_loss_keeps_the_table_but_lets_the_patch_fill_it():
    """L_keep penalises opacity the patch takes away under the box, not opacity it adds (a
    support the object hid from every camera is part empty in the unedited field)."""
    from neoedit.edit.removal_loss import support_loss

    kept = torch.tensor([0.9, 0.3])  # a seen table, a hidden one
    same = -100.0 * torch.log1p(-kept)  # the densities that give those opacities over 1 cm
    assert float(support_loss(same, kept)) == pytest.approx(0.0, abs=1e-6)
    filled = torch.tensor([same[0].item(), 500.0], requires_grad=True)  # the hidden one filled
    assert float(support_loss(filled, kept).detach()) == pytest.approx(0.0, abs=1e-6)
    emptied = torch.tensor([0.0, same[1].item()], requires_grad=True)  # the seen one emptied
    loss = support_loss(emptied, kept)
    assert float(loss.detach()) == pytest.approx(0.45, abs=1e-4)
    loss.backward()
    assert emptied.grad[0] < 0 and emptied.grad[1] == 0  # only the emptied point is pushed up


def test_grow_mask_is_a_disc_dilation():
    """Growing a hole is a dilation by a disc of the radius (brute force on a small image)."""
    import numpy as np

    from neoedit.edit.refine import grow_mask

    rng = np.random.default_rng(0)
    mask = rng.random((40, 50)) > 0.97
    for radius in (0.0, 1.5, 4.0, 9.3):
        grown = grow_mask(mask, radius)
        ys, xs = np.nonzero(mask)
        yy, xx = np.mgrid[:40, :50]
        d = np.sqrt((yy[..., None] - ys) ** 2 + (xx[..., None] - xs) ** 2).min(-1)
        np.testing.assert_array_equal(grown, d <= radius)
    assert not grow_mask(np.zeros((5, 5), bool), 3.0).any()


def test_surface_level_finds_the_top_surface_and_is_never_nan():
    """The level of a table among fog above it, of a coaster's rim over the table (the
    higher crowded surface: seating a box there never cuts into the coaster), and a finite
    level when the crowded band's centre holds no point."""
    from neoedit.geometry.levels import surface_level

    rng = np.random.default_rng(0)
    table = rng.normal(0.0, 0.001, 400)
    fog = rng.uniform(0.003, 0.02, 150)
    assert surface_level(np.r_[table, fog]) == pytest.approx(0.0, abs=0.0015)
    coaster = rng.normal(0.008, 0.001, 300)
    assert surface_level(np.r_[table, coaster]) == pytest.approx(0.008, abs=0.0015)
    split = np.r_[np.zeros(5), np.full(5, 0.009)]  # one 9 mm bin, nothing near its median
    assert np.isfinite(surface_level(split))
