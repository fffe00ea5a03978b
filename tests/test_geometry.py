import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from neoedit.errors import NeoError
from neoedit.geometry import OrientedBox, rot_z
from neoedit.geometry.box import box_iou_3d
from neoedit.geometry.transforms import make_transform


def yaw_distance_deg(a: float, b: float, period: float) -> float:
    d = (a - b) % period
    return min(d, period - d)


@settings(max_examples=60, deadline=None)
@given(
    yaw=st.floats(-180, 180),
    sx=st.floats(0.05, 0.4),
    sy=st.floats(0.02, 0.3),
    sz=st.floats(0.02, 0.3),
    cx=st.floats(-1, 1),
    cy=st.floats(-1, 1),
)
def test_fit_recovers_box_from_surface_points(yaw, sx, sy, sz, cx, cy):
    truth = OrientedBox((cx, cy, sz / 2), (sx, sy, sz), yaw)
    rng = np.random.default_rng(0)
    local = rng.uniform(-0.5, 0.5, size=(3000, 3)) * np.asarray(truth.size_m)
    # push samples onto the faces, plus the 8 corners (a surface scan of a box)
    axis = rng.integers(0, 3, len(local))
    local[np.arange(len(local)), axis] = (
        np.sign(local[np.arange(len(local)), axis]) * np.asarray(truth.size_m)[axis] / 2
    )
    pts = np.concatenate([local @ rot_z(yaw).T + truth.center_m, truth.corners()])
    fit = OrientedBox.fit_to_points(pts)
    assert np.allclose(fit.center_m, truth.center_m, atol=1e-3)
    assert np.allclose(sorted(fit.size_m[:2]), sorted(truth.size_m[:2]), atol=2e-3)
    assert fit.size_m[2] == pytest.approx(sz, abs=1e-3)
    assert fit.size_m[0] >= fit.size_m[1]
    if abs(sx - sy) > 0.01:  # yaw is defined modulo 180 deg (modulo 90 for squares)
        long_yaw = yaw if sx >= sy else yaw + 90
        assert yaw_distance_deg(fit.yaw_deg, long_yaw, 180) < 0.5
    assert box_iou_3d(fit, truth) > 0.97


def test_contains_and_corners():
    box = OrientedBox((0.1, -0.2, 0.05), (0.2, 0.1, 0.1), 30.0)
    assert box.contains(box.corners(), margin_m=1e-9).all()
    assert box.contains(np.array([box.center_m])).all()
    far = np.asarray(box.center_m) + rot_z(30) @ np.array([0.11, 0.0, 0.0])
    assert not box.contains(far[None])[0]


def test_iou_identity_and_disjoint():
    a = OrientedBox((0, 0, 0), (1, 1, 1), 10)
    assert box_iou_3d(a, a) == pytest.approx(1.0, abs=1e-5)
    assert box_iou_3d(a, OrientedBox((3, 0, 0), (1, 1, 1), 10)) == 0.0
    # half-overlap along x of two axis-aligned unit cubes: 0.5 / 1.5
    assert box_iou_3d(
        OrientedBox((0, 0, 0), (1, 1, 1)), OrientedBox((0.5, 0, 0), (1, 1, 1))
    ) == pytest.approx(1 / 3, abs=1e-4)


def test_transformed_moves_points_with_box():
    box = OrientedBox((0.1, 0.2, 0.05), (0.2, 0.1, 0.1), 15)
    t = make_transform(rot_z(40), np.array([0.3, -0.1, 0.02]))
    moved = box.transformed(t)
    corners = box.corners() @ t[:3, :3].T + t[:3, 3]
    assert moved.contains(corners, margin_m=1e-6).all()
    assert moved.yaw_deg == pytest.approx(55)


def test_box_dict_roundtrip_and_errors():
    box = OrientedBox((0.1, 0.2, 0.3), (0.1, 0.2, 0.3), 12.5)
    assert OrientedBox.from_dict(box.to_dict()) == box
    with pytest.raises(NeoError):
        OrientedBox.from_dict({"center": [0, 0]})
    with pytest.raises(NeoError):
        OrientedBox((0, 0, 0), (0, 1, 1))


@settings(max_examples=40, deadline=None)
@given(
    yaw_a=st.floats(-90, 90),
    yaw_b=st.floats(-90, 90),
    dx=st.floats(-0.3, 0.3),
    dz=st.floats(-0.1, 0.1),
)
def test_iou_matches_monte_carlo(yaw_a, yaw_b, dx, dz):
    a = OrientedBox((0, 0, 0), (0.4, 0.2, 0.2), yaw_a)
    b = OrientedBox((dx, 0.05, dz), (0.3, 0.25, 0.15), yaw_b)
    corners = np.concatenate([a.corners(), b.corners()])
    pts = np.random.default_rng(1).uniform(corners.min(0), corners.max(0), size=(300_000, 3))
    ia, ib = a.contains(pts), b.contains(pts)
    union = (ia | ib).sum()
    expected = (ia & ib).sum() / union if union else 0.0
    assert box_iou_3d(a, b) == pytest.approx(expected, abs=0.01)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_core_clusters_equal_dbscans_core_points(seed):
    """The query's clustering against scikit-learn's DBSCAN on blobs, a ring and noise:
    the same core points, grouped into the same clusters (ids may differ)."""
    from sklearn.cluster import DBSCAN

    from neoedit.geometry.clusters import core_clusters

    rng = np.random.default_rng(seed)
    blobs = [rng.normal(c, 0.02, (150, 3)) for c in ((0, 0, 0), (0.2, 0, 0), (0, 0.25, 0.1))]
    t = rng.uniform(0, 2 * np.pi, 200)
    ring = np.stack([0.5 + 0.1 * np.cos(t), 0.1 * np.sin(t), np.zeros_like(t)], 1)
    pts = np.concatenate([*blobs, ring, rng.uniform(-0.5, 0.8, (300, 3))])
    eps, min_samples = 0.03, 5
    labels, core = core_clusters(pts, eps, min_samples)
    db = DBSCAN(eps=eps, min_samples=min_samples).fit(pts)
    ref_core = np.zeros(len(pts), bool)
    ref_core[db.core_sample_indices_] = True
    assert np.array_equal(core, ref_core) and core.sum() > 500
    assert (labels[~core] == -1).all() and (labels[core] >= 0).all()
    ours, theirs = labels[core], db.labels_[core]
    pairs = set(zip(ours.tolist(), theirs.tolist(), strict=True))
    assert len(pairs) == len(set(ours.tolist())) == len(set(theirs.tolist())) >= 4
    empty_labels, empty_core = core_clusters(np.zeros((0, 3)), eps, min_samples)
    assert empty_labels.shape == (0,) and empty_core.shape == (0,)
    lonely, _ = core_clusters(pts[:3] * 100, eps, min_samples)  # no point is core
    assert (lonely == -1).all()
