"""What a training resolves from its data: the hash grid's finest resolution."""

from __future__ import annotations

import dataclasses
from types import SimpleNamespace

import numpy as np
import pytest

from neoedit.cameras import Cameras
from neoedit.cameras.cameras import look_at
from neoedit.fields.hashgrid import HashGridConfig, level_resolutions
from neoedit.fields.radiance import RadianceFieldConfig
from neoedit.training.defaults import field_config, finest_resolution

BOX = np.array([[-0.75, -0.5, -0.05], [0.75, 0.5, 0.38]])  # NEO-Sim's table box, 1.5 m long


def ring(fx: float, distance_m: float = 0.75, n: int = 12) -> SimpleNamespace:
    """Photos (their cameras only) from a ring around the box centre, looking at it."""
    angles = np.linspace(0, 2 * np.pi, n, endpoint=False)
    eyes = np.stack(
        [distance_m * np.cos(angles) * 0.8, distance_m * np.sin(angles) * 0.8, np.full(n, 0.0)],
        1,
    )
    eyes[:, 2] = distance_m * 0.6  # 0.8^2 + 0.6^2 = 1: every camera distance_m from the centre
    c2w = np.stack([look_at(e, np.zeros(3)) for e in eyes])
    k = np.full(n, fx)
    cams = Cameras(
        c2w, k, k, np.full(n, 160.0), np.full(n, 120.0), np.full(n, 320), np.full(n, 240)
    )
    return SimpleNamespace(cameras=cams, alpha=None)  # photos (field_config reads the alpha)


@pytest.mark.parametrize(
    ("fx", "expected"),
    [(230.5, 512), (60.0, 256), (4000.0, 1024)],  # NEO-Sim's 320x240; a tiny scan; 4K photos
)
def test_the_finest_cells_match_the_pixel_footprint(fx, expected):
    data = ring(fx)
    chosen = finest_resolution(data, BOX)
    assert chosen == expected
    footprint = 0.75 / fx
    cell = 1.5 / chosen
    if 256 < chosen < 1024:  # not clamped: the cells just smaller than a pixel's footprint
        assert cell <= footprint < 2 * cell


def test_training_resolves_only_the_automatic_resolution():
    data = ring(230.5)
    auto = field_config(RadianceFieldConfig(), data, BOX)
    assert RadianceFieldConfig().hashgrid.max_resolution == 0
    assert auto.hashgrid.max_resolution == 512
    assert level_resolutions(auto.hashgrid)[-1] == 512
    given = dataclasses.replace(RadianceFieldConfig(), hashgrid=HashGridConfig(max_resolution=2048))
    assert field_config(given, data, BOX).hashgrid.max_resolution == 2048  # the user's value
    # an automatic resolution no data resolved (a field built without neo train) is 1024
    assert level_resolutions(HashGridConfig(max_resolution=0)) == level_resolutions(
        HashGridConfig(max_resolution=1024)
    )
