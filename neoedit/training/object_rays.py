"""More training rays on the objects: a share of each batch drawn from the objects' pixels.

A tabletop scan is mostly table: on NEO-Sim pick_place_1 the red mug covers 1.1 % of the
training pixels and the soccer ball 0.9 %, so a 3-minute training gives each ~20 k rays.
Fitted on its own pixels, the mug needs ~200 k rays to reach 23 dB on them, and the objects
render blurred and tinted by the table (benchmarks/RESULTS.md, "Fidelity"). Where the
dataset labels its objects (instance images and ``objects.json``: NEO-Sim scans, or a user's
own masks), :class:`ObjectRays` replaces a share of each batch's random pixels by pixels
drawn uniformly from the objects'. The loss is not reweighted: the objects are meant to
weigh more than their area.
"""

from __future__ import annotations

import numpy as np
import torch

from neoedit.data import SceneData
from neoedit.errors import NeoError


def object_instance_ids(data: SceneData) -> list[int]:
    """The instance ids of the dataset's objects (``objects.json``'s ``objects``, which
    leaves out the table, the robot and the background)."""
    ids = set()
    for entry in data.objects:
        value = entry.get("id")
        if isinstance(value, bool) or not isinstance(value, int):
            raise NeoError(
                f"{data.root}/objects.json: object {entry.get('name')!r} has no integer 'id' "
                f"(got {value!r}); --object-ray-share finds an object's pixels by that id"
            )
        ids.add(value)
    return sorted(ids)


class ObjectRays:
    """The (K, 3) training-image index, row and column of every object pixel of the training
    views, and a sampler that mixes them into a batch."""

    def __init__(self, data: SceneData, share: float, device: torch.device | str = "cpu"):
        missing = (
            "instance images (nerfstudio frames' instance_path)"
            if data.instance_ids is None
            else "objects in objects.json"
            if not data.objects
            else None
        )
        if missing is not None:
            raise NeoError(
                f"--object-ray-share {share} needs a dataset that labels its objects "
                f"(instance images and objects.json with their ids, as NEO-Sim writes); "
                f"{data.root} has no {missing}: drop the option"
            )
        ids = object_instance_ids(data)
        train = data.split["train"]
        on_object = np.isin(np.asarray(data.instance_ids)[train], ids)
        if data.loss_mask is not None:  # pixels left out of the loss are not drawn either
            on_object &= data.loss_mask[train]
        where = np.argwhere(on_object)
        if len(where) == 0:
            raise NeoError(
                f"--object-ray-share {share}: no training view of {data.root} shows an object "
                f"(instance ids {ids}); drop the option"
            )
        self.pixels = torch.as_tensor(where, dtype=torch.long, device=device)
        self.share = share

    def mix(
        self,
        img: torch.Tensor,
        v: torch.Tensor,
        u: torch.Tensor,
        generator: torch.Generator | None = None,
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """The batch (image, row, column; each (N,)) with its last ``share`` * N pixels
        replaced by object pixels drawn uniformly (with replacement)."""
        n_obj = int(round(self.share * len(img)))
        if n_obj == 0:
            return img, v, u
        pick = torch.randint(
            0, len(self.pixels), (n_obj,), device=self.pixels.device, generator=generator
        )
        drawn = self.pixels[pick]
        keep = len(img) - n_obj
        return tuple(  # type: ignore[return-value]
            torch.cat([a[:keep], drawn[:, k]]) for k, a in enumerate((img, v, u))
        )
