"""The ArUco dictionaries neoedit accepts (OpenCV ``aruco``), shared by the marker detector
(:mod:`neoedit.data.markers`) and the simulator's marker textures (:mod:`neoedit.sim.markers`)."""

from __future__ import annotations

from typing import Any

from neoedit.errors import DataError

DICTIONARIES = {
    "4X4_50": 50,
    "4X4_100": 100,
    "5X5_50": 50,
    "5X5_100": 100,
    "6X6_50": 50,
    "6X6_250": 250,
    "ARUCO_ORIGINAL": 1024,
}
"""Name -> number of marker ids."""


def aruco_dictionary(name: str) -> Any:
    """The OpenCV dictionary called ``name`` (e.g. '4X4_50')."""
    import cv2

    if name not in DICTIONARIES:
        raise DataError(f"unknown ArUco dictionary {name!r} (choose {', '.join(DICTIONARIES)})")
    return cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, f"DICT_{name}"))
