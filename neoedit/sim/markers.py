"""ArUco markers lying on the NEO-Sim table (the paper's tables carry them for registration).

Each marker is a thin visual-only quad with the marker texture (a white quiet zone of a
quarter side around it), a few tenths of a millimetre above the table top. Ground truth:
:func:`marker_corners` gives its four corners in the world, in OpenCV's corner order.
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np

from neoedit.geometry.transforms import rot_z
from neoedit.sim._pybullet import pb
from neoedit.sim.spec import MarkerSpec
from neoedit.utils.aruco import aruco_dictionary

LIFT_M = 0.0004
"""Height of the marker quads above the table top (no z-fighting, no visible step)."""


def marker_corners(marker: MarkerSpec) -> np.ndarray:
    """(4,3) world corners in OpenCV's order (the marker image's top-left, top-right,
    bottom-right, bottom-left), with the image's top towards +y before the yaw."""
    h = marker.side_m / 2
    local = np.array([[-h, h, 0.0], [h, h, 0.0], [h, -h, 0.0], [-h, -h, 0.0]])
    centre = np.array([*marker.center_m, LIFT_M])
    return local @ rot_z(marker.yaw_deg).T + centre


def _texture(marker: MarkerSpec, path: Path, cells_px: int = 48) -> None:
    import cv2

    dictionary = aruco_dictionary(marker.dictionary)
    side = (dictionary.markerSize + 2) * cells_px  # the bits + the black border
    pad = side // 4
    image = np.full((side + 2 * pad, side + 2 * pad), 255, np.uint8)
    image[pad : pad + side, pad : pad + side] = cv2.aruco.generateImageMarker(
        dictionary, marker.id, side
    )
    cv2.imwrite(str(path), image)


def _quad(half: float, path: Path) -> None:
    """A square in z = 0 with texture coordinates (v up: the image's top row at +y)."""
    path.write_text(
        "\n".join(
            [
                f"v {-half} {-half} 0",
                f"v {half} {-half} 0",
                f"v {half} {half} 0",
                f"v {-half} {half} 0",
                "vt 0 0",
                "vt 1 0",
                "vt 1 1",
                "vt 0 1",
                "vn 0 0 1",
                "f 1/1/1 2/2/1 3/3/1",
                "f 1/1/1 3/3/1 4/4/1",
            ]
        )
        + "\n"
    )


def add_markers(client: int, markers: list[MarkerSpec]) -> list[int]:
    """Create the marker quads in the PyBullet world ``client``; their body ids."""
    bodies = []
    with tempfile.TemporaryDirectory(prefix="neoedit-markers-") as tmp:
        for k, marker in enumerate(markers):
            obj, png = Path(tmp) / f"marker{k}.obj", Path(tmp) / f"marker{k}.png"
            _quad(0.75 * marker.side_m, obj)
            _texture(marker, png)
            visual = pb.createVisualShape(pb.GEOM_MESH, fileName=str(obj), physicsClientId=client)
            orn = pb.getQuaternionFromEuler([0, 0, np.radians(marker.yaw_deg)])
            body = pb.createMultiBody(
                baseMass=0,
                baseVisualShapeIndex=visual,
                basePosition=[*marker.center_m, LIFT_M],
                baseOrientation=orn,
                physicsClientId=client,
            )
            texture = pb.loadTexture(str(png), physicsClientId=client)
            pb.changeVisualShape(
                body, -1, textureUniqueId=texture, rgbaColor=[1, 1, 1, 1], physicsClientId=client
            )
            bodies.append(body)
    return bodies
