"""2-D inpainting of virtual views: backends behind one interface, and the 2x2 grid trick.

Backends (``make_inpainter``):

* ``telea`` / ``ns`` (OpenCV ``cv2.inpaint``: Telea's fast marching, Navier-Stokes) and
  ``fsr`` (opencv-contrib ``xphoto`` frequency-selective reconstruction, FSR_FAST): the
  embedded defaults, no weights.
* ``diffusion``: a ``diffusers`` inpainting pipeline from a local directory (e.g. a Stable
  Diffusion inpainting checkpoint saved with ``save_pretrained``); ``strength`` is the
  paper's xi (how far the masked pixels may move from the given image).

For the OpenCV backends ``strength`` blends the inpainted pixels with the given image:
out = xi * inpainted + (1 - xi) * image inside the mask (the paper's progressive
refinement with decreasing xi then pulls the targets towards the field's own rendering).

Grid inpainting (Sec. III-B): four virtual views of similar elevation are tiled into one
2x2 composite, inpainted together (the inpainter sees the same surface from four sides)
and split back.
"""

from __future__ import annotations

from typing import Any, Protocol

import cv2
import numpy as np

from neoedit.errors import NeoError

OPENCV_METHODS = ("telea", "ns", "fsr")
INPAINTERS = (*OPENCV_METHODS, "diffusion")


class Inpainter(Protocol):
    name: str

    def inpaint(self, image: np.ndarray, mask: np.ndarray, strength: float) -> np.ndarray:
        """image (H,W,3) uint8, mask (H,W) bool (True = fill) -> (H,W,3) uint8; pixels
        outside the mask are returned unchanged."""
        ...


def _blend(image: np.ndarray, filled: np.ndarray, mask: np.ndarray, strength: float) -> np.ndarray:
    xi = float(np.clip(strength, 0.0, 1.0))
    out = image.astype(np.float32)
    m = mask[..., None]
    out = np.where(m, xi * filled.astype(np.float32) + (1.0 - xi) * out, out)
    return out.round().clip(0, 255).astype(np.uint8)


class OpenCVInpainter:
    def __init__(self, method: str = "telea", radius_px: int = 5):
        if method not in OPENCV_METHODS:
            raise NeoError(
                f"unknown OpenCV inpainting method {method!r} (choose from {', '.join(OPENCV_METHODS)})"
            )
        if method == "fsr" and not hasattr(cv2, "xphoto"):
            raise NeoError("the 'fsr' inpainter needs opencv-contrib (cv2.xphoto)")
        self.name, self.method, self.radius_px = method, method, radius_px

    def inpaint(self, image: np.ndarray, mask: np.ndarray, strength: float = 1.0) -> np.ndarray:
        if not mask.any():
            return image.copy()
        if self.method == "fsr":
            bgr = cv2.cvtColor(image, cv2.COLOR_RGB2BGR)
            known = (~mask).astype(np.uint8)
            dst = np.zeros_like(bgr)
            cv2.xphoto.inpaint(bgr, known, dst, cv2.xphoto.INPAINT_FSR_FAST)
            filled = cv2.cvtColor(dst, cv2.COLOR_BGR2RGB)
        else:
            flag = cv2.INPAINT_TELEA if self.method == "telea" else cv2.INPAINT_NS
            filled = cv2.inpaint(image, mask.astype(np.uint8), self.radius_px, flag)
        return _blend(image, filled, mask, strength)


class DiffusionInpainter:
    """A diffusers inpainting pipeline from a local directory (no downloads)."""

    name = "diffusion"

    def __init__(
        self,
        path: str | None,
        prompt: str = "",
        steps: int = 25,
        seed: int = 0,
        device: str = "cpu",
    ):
        if not path:
            raise NeoError(
                "the diffusion inpainter needs a local pipeline directory (--inpaint-path)"
            )
        try:
            from diffusers import AutoPipelineForInpainting
        except ImportError:
            raise NeoError(
                "the diffusion inpainter needs diffusers: pip install 'neoedit[diffusion]'"
            ) from None
        from pathlib import Path

        if not (Path(path) / "model_index.json").is_file():
            raise NeoError(f"diffusion inpainting pipeline not found: {path} (no model_index.json)")
        try:
            self.pipe: Any = AutoPipelineForInpainting.from_pretrained(
                path, local_files_only=True
            ).to(device)
        except (OSError, ValueError) as e:
            raise NeoError(f"cannot load the inpainting pipeline from {path}: {e}") from None
        self.pipe.set_progress_bar_config(disable=True)
        self.prompt, self.steps, self.seed, self.device = prompt, steps, seed, device

    def inpaint(self, image: np.ndarray, mask: np.ndarray, strength: float = 1.0) -> np.ndarray:
        import torch
        from PIL import Image

        if not mask.any():
            return image.copy()
        h, w = image.shape[:2]
        ph, pw = -h % 64, -w % 64  # pad to a size every UNet level divides (SD needs /8)
        img = np.pad(image, ((0, ph), (0, pw), (0, 0)), mode="edge")
        msk = np.pad(mask, ((0, ph), (0, pw)))
        out = self.pipe(
            prompt=self.prompt,
            image=Image.fromarray(img),
            mask_image=Image.fromarray((msk * 255).astype(np.uint8)),
            strength=float(np.clip(strength, 0.01, 1.0)),
            num_inference_steps=self.steps,
            height=img.shape[0],
            width=img.shape[1],
            generator=torch.Generator(self.device).manual_seed(self.seed),
            output_type="np",
        ).images[0]
        filled = (np.asarray(out)[:h, :w] * 255).round().clip(0, 255).astype(np.uint8)
        return _blend(image, filled, mask, 1.0)  # strength already acted inside the pipeline


def make_inpainter(
    name: str, path: str | None = None, prompt: str = "", device: str = "cpu"
) -> Inpainter:
    if name in OPENCV_METHODS:
        return OpenCVInpainter(name)
    if name == "diffusion":
        return DiffusionInpainter(path, prompt=prompt, device=device)
    raise NeoError(f"unknown inpainter {name!r} (choose from {', '.join(INPAINTERS)})")


def tile_2x2(images: list[np.ndarray]) -> np.ndarray:
    """Four (H,W,...) arrays -> one (2H,2W,...) composite: [[0, 1], [2, 3]]."""
    if len(images) != 4 or len({im.shape for im in images}) != 1:
        raise ValueError("tile_2x2 needs four arrays of one shape")
    return np.concatenate([np.concatenate(images[:2], 1), np.concatenate(images[2:], 1)], 0)


def split_2x2(composite: np.ndarray) -> list[np.ndarray]:
    """Inverse of :func:`tile_2x2`."""
    h, w = composite.shape[0] // 2, composite.shape[1] // 2
    return [composite[:h, :w], composite[:h, w:], composite[h:, :w], composite[h:, w:]]


MIN_CONTEXT = 0.1
"""An image keeps its ``avoid`` pixels as context when leaving them out would leave less than
this share of its unmasked pixels (nothing else to fill from)."""


def inpaint_views(
    inpainter: Inpainter,
    images: list[np.ndarray],
    masks: list[np.ndarray],
    strength: float,
    grid: bool = True,
    avoid: list[np.ndarray] | None = None,
) -> list[np.ndarray]:
    """Inpaint views in groups of four tiled 2x2 (``grid``), or one by one. ``avoid`` (per
    view (h,w) bool): pixels the fill must not be drawn from (they are hidden from the
    inpainter with the mask, then put back as they were)."""
    if avoid is not None:
        hidden = [_with_avoided(m, a) for m, a in zip(masks, avoid, strict=True)]
        filled = inpaint_views(inpainter, images, hidden, strength, grid)
        return [
            np.where((h & ~m)[..., None], im, f)
            for im, m, h, f in zip(images, masks, hidden, filled, strict=True)
        ]
    out: list[np.ndarray] = []
    k = 0
    while k < len(images):
        if grid and k + 4 <= len(images):
            comp = inpainter.inpaint(
                tile_2x2(images[k : k + 4]), tile_2x2(masks[k : k + 4]), strength
            )
            out.extend(np.ascontiguousarray(p) for p in split_2x2(comp))
            k += 4
        else:
            out.append(inpainter.inpaint(images[k], masks[k], strength))
            k += 1
    return out


def _with_avoided(mask: np.ndarray, avoid: np.ndarray) -> np.ndarray:
    """``mask`` with the ``avoid`` pixels added, unless that leaves too little context."""
    if not mask.any():
        return mask
    both = mask | avoid
    return both if (~both).sum() >= MIN_CONTEXT * (~mask).sum() else mask
