"""2-D teachers: per-pixel feature targets for the language field.

A teacher is prepared once on the training frames of a dataset and then answers
``targets_at(points, frame, v, u) -> (features (N,D), valid (N,))`` for the surface points
(N,3) the training rendered and the pixels they were seen at (frame is the position in the
prepared frame list, (v, u) full-resolution pixel rows / columns). Image teachers only look
at the pixel (their ``targets(frame, v, u)``; :class:`PixelTeacher` supplies ``targets_at``);
the geometric teacher (:mod:`neoedit.language.geometric`) looks at the points.

* :class:`LabelTeacher` (embedded default): instance masks + names -> the text embedding of
  the name at every pixel. Pixels on a label boundary are left out (their depth may belong
  to either side).
* :class:`CLIPTeacher`: LERF-style multi-scale patch pyramid of a CLIP image tower; the
  scales are averaged into one feature map per image (LERF instead conditions the field on
  the scale; averaging keeps one head and one query pass).
* :class:`DinoTeacher`: DINOv2 patch features (an auxiliary target, as in LERF).
"""

from __future__ import annotations

from typing import Protocol

import numpy as np
import torch
import torch.nn.functional as F

from neoedit.data import SceneData
from neoedit.errors import NeoError
from neoedit.language.clip import features_tensor, load_clip, load_dino
from neoedit.language.text import TextEncoder
from neoedit.utils.progress import track


class Teacher(Protocol):
    name: str
    dim: int

    def prepare(self, data: SceneData, frames: np.ndarray) -> None: ...

    def targets_at(
        self, points: torch.Tensor, frame: torch.Tensor, v_px: torch.Tensor, u_px: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]: ...


class PixelTeacher:
    """Base of the teachers whose target depends on the pixel only."""

    def targets(
        self, frame: torch.Tensor, v_px: torch.Tensor, u_px: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        raise NotImplementedError

    def targets_at(
        self, points: torch.Tensor, frame: torch.Tensor, v_px: torch.Tensor, u_px: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        return self.targets(frame, v_px, u_px)


class LabelTeacher(PixelTeacher):
    name = "labels"

    def __init__(self, text: TextEncoder):
        self.text = text
        self.dim = text.dim
        self.names: list[str] = []

    def prepare(self, data: SceneData, frames: np.ndarray) -> None:
        if data.instance_ids is None or not data.instance_names:
            raise NeoError(
                f"{data.root}: the label teacher needs instance masks and names "
                "(instance_path per frame + objects.json 'instances'); use --teacher clip or "
                "--no-language"
            )
        ids = data.instance_ids[frames]
        present = sorted(int(i) for i in np.unique(ids) if int(i) in data.instance_names)
        self.names = [data.instance_names[i] for i in present]
        self.table = self.text.encode(self.names)  # (K, D)
        lookup = np.full(max(int(ids.max()), max(present)) + 1, -1, np.int16)
        lookup[present] = np.arange(len(present))
        rows = lookup[ids]
        # leave out label boundaries: a pixel counts only if its 4 neighbours share its label
        same = np.ones_like(rows, dtype=bool)
        same[:, 1:, :] &= rows[:, 1:, :] == rows[:, :-1, :]
        same[:, :-1, :] &= rows[:, :-1, :] == rows[:, 1:, :]
        same[:, :, 1:] &= rows[:, :, 1:] == rows[:, :, :-1]
        same[:, :, :-1] &= rows[:, :, :-1] == rows[:, :, 1:]
        rows[~same] = -1
        self.rows = torch.from_numpy(rows.astype(np.int64))

    def targets(self, frame, v_px, u_px):
        rows = self.rows[frame.cpu(), v_px.cpu(), u_px.cpu()]
        valid = rows >= 0
        return self.table[rows.clamp_min(0)], valid


class _FeatureMapTeacher(PixelTeacher):
    """Shared part of the image-model teachers: (F, h, w, D) float16 maps, nearest lookup."""

    maps: torch.Tensor
    height: int
    width: int

    def targets(self, frame, v_px, u_px):
        _, fh, fw, _ = self.maps.shape
        fv = ((v_px.cpu().float() + 0.5) * fh / self.height).long().clamp(0, fh - 1)
        fu = ((u_px.cpu().float() + 0.5) * fw / self.width).long().clamp(0, fw - 1)
        feats = self.maps[frame.cpu(), fv, fu].float()
        return feats, torch.ones(len(feats), dtype=torch.bool)


def _image_tensor(data: SceneData, i: int) -> torch.Tensor:
    return torch.from_numpy(data.images[i]).permute(2, 0, 1)[None].float() / 255.0  # (1,3,H,W)


class CLIPTeacher(_FeatureMapTeacher):
    name = "clip"

    def __init__(
        self,
        path: str,
        scales: tuple[float, ...] = (0.15, 0.3, 0.5),
        downsample: int = 8,
        batch: int = 64,
    ):
        self.model, _, (self.mean, self.std) = load_clip(path)
        self.dim = int(self.model.config.projection_dim)
        self.size = int(self.model.config.vision_config.image_size)
        self.scales, self.downsample, self.batch = scales, downsample, batch

    @torch.no_grad()
    def _embed(self, crops: torch.Tensor) -> torch.Tensor:
        out = []
        for start in range(0, len(crops), self.batch):
            x = F.interpolate(
                crops[start : start + self.batch],
                size=(self.size, self.size),
                mode="bilinear",
                align_corners=False,
                antialias=True,
            )
            feats = features_tensor(
                self.model.get_image_features(pixel_values=(x - self.mean) / self.std)
            )
            out.append(F.normalize(feats.float(), dim=-1))
        return torch.cat(out)

    def image_features(self, image: torch.Tensor) -> torch.Tensor:
        """(1,3,H,W) in [0,1] -> (h, w, D) unit features, averaged over the patch scales."""
        _, _, h, w = image.shape
        fh, fw = max(h // self.downsample, 1), max(w // self.downsample, 1)
        total = torch.zeros(self.dim, fh, fw)
        for scale in self.scales:
            patch = max(int(round(scale * min(h, w))), 4)
            stride = max(patch // 2, 1)
            pad = patch // 2
            padded = F.pad(image, (pad, pad, pad, pad), mode="reflect")
            cols = F.unfold(padded, kernel_size=patch, stride=stride)  # (1, 3*p*p, L)
            gh = (h + 2 * pad - patch) // stride + 1
            gw = (w + 2 * pad - patch) // stride + 1
            crops = cols[0].T.reshape(-1, 3, patch, patch)
            grid = self._embed(crops).T.reshape(1, self.dim, gh, gw)
            total += F.interpolate(grid, size=(fh, fw), mode="bilinear", align_corners=True)[0]
        return F.normalize(total, dim=0).permute(1, 2, 0)

    def prepare(self, data: SceneData, frames: np.ndarray) -> None:
        self.height, self.width = data.height, data.width
        self.maps = torch.stack(
            [
                self.image_features(_image_tensor(data, int(i))).half()
                for i in track(frames, "CLIP features")
            ]
        )


class DinoTeacher(_FeatureMapTeacher):
    name = "dino"

    def __init__(self, path: str, downsample: int = 8):
        self.model, (self.mean, self.std) = load_dino(path)
        self.dim = int(self.model.config.hidden_size)
        self.patch = int(self.model.config.patch_size)
        self.downsample = downsample

    @torch.no_grad()
    def image_features(self, image: torch.Tensor) -> torch.Tensor:
        """(1,3,H,W) in [0,1] -> (h, w, D) patch features."""
        _, _, h, w = image.shape
        gh, gw = max(round(h / self.patch), 1), max(round(w / self.patch), 1)
        x = F.interpolate(
            image,
            size=(gh * self.patch, gw * self.patch),
            mode="bilinear",
            align_corners=False,
            antialias=True,
        )
        tokens = self.model(pixel_values=(x - self.mean) / self.std).last_hidden_state
        grid = tokens[0, -gh * gw :].T.reshape(1, self.dim, gh, gw)
        fh, fw = max(h // self.downsample, 1), max(w // self.downsample, 1)
        return F.interpolate(grid, size=(fh, fw), mode="bilinear", align_corners=True)[0].permute(
            1, 2, 0
        )

    def prepare(self, data: SceneData, frames: np.ndarray) -> None:
        self.height, self.width = data.height, data.width
        self.maps = torch.stack(
            [
                self.image_features(_image_tensor(data, int(i))).half()
                for i in track(frames, "DINO features")
            ]
        )
