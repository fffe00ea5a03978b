import numpy as np
import pytest

from neoedit.cameras import Cameras, look_at
from neoedit.cameras.cameras import validate_pose
from neoedit.errors import NeoError


def test_look_at_is_rigid_and_points_at_target():
    c2w = look_at(np.array([0.5, -0.3, 0.4]), np.array([0.0, 0.1, 0.0]))
    r = c2w[:3, :3]
    assert np.allclose(r.T @ r, np.eye(3), atol=1e-12)
    assert np.linalg.det(r) == pytest.approx(1.0)
    forward = -r[:, 2]  # OpenGL: the camera looks down -z
    to_target = np.array([0.0, 0.1, 0.0]) - c2w[:3, 3]
    assert np.allclose(forward, to_target / np.linalg.norm(to_target))
    assert r[2, 1] > 0  # image up has a positive world-z component


def test_backproject_project_roundtrip():
    cams = Cameras(
        look_at(np.array([0.6, 0.2, 0.5]), np.zeros(3))[None], 50.0, 52.0, 31.0, 23.0, 64, 48
    )
    depth = np.random.default_rng(0).uniform(0.3, 1.5, size=(48, 64))
    pts = cams.backproject_depth(0, depth)
    uv, z = cams.project(0, pts.reshape(-1, 3))
    u, v = np.meshgrid(np.arange(64) + 0.5, np.arange(48) + 0.5)
    assert np.allclose(uv[:, 0], u.ravel()) and np.allclose(uv[:, 1], v.ravel())
    assert np.allclose(z, depth.ravel())


@pytest.mark.parametrize(
    "matrix, message",
    [
        (np.full((4, 4), np.nan), "non-finite"),
        (np.zeros((4, 4)), "not invertible"),
        (np.eye(3), "4x4"),
    ],
)
def test_validate_pose_errors(matrix, message):
    with pytest.raises(NeoError, match=message):
        validate_pose(matrix, "frame 0")
