"""Loading CLIP and DINOv2 from local checkpoint directories (``transformers``; no downloads).

A checkpoint directory is what ``CLIPModel.save_pretrained`` / ``Dinov2Model.save_pretrained``
write (config.json + weights), plus the tokenizer files for CLIP. Image normalisation comes
from ``preprocessor_config.json`` when present, otherwise the published CLIP / ImageNet values.
"""

from __future__ import annotations

import functools
import json
from pathlib import Path
from typing import Any

import torch

from neoedit.errors import NeoError

CLIP_MEAN = (0.48145466, 0.4578275, 0.40821073)
CLIP_STD = (0.26862954, 0.26130258, 0.27577711)
IMAGENET_MEAN = (0.485, 0.456, 0.406)
IMAGENET_STD = (0.229, 0.224, 0.225)


def check_checkpoint(path: str | Path | None, what: str) -> Path:
    """A local checkpoint folder (a NeoError naming ``what`` when it is not one)."""
    if not path:
        raise NeoError(f"the {what} encoder needs a local checkpoint directory")
    p = Path(path)
    if not (p / "config.json").is_file():
        raise NeoError(f"{what} checkpoint not found: {p} (expected a directory with config.json)")
    return p


def _normalisation(path: Path, mean: tuple, std: tuple) -> tuple[torch.Tensor, torch.Tensor]:
    cfg_file = path / "preprocessor_config.json"
    if cfg_file.is_file():
        cfg = json.loads(cfg_file.read_text())
        mean, std = tuple(cfg.get("image_mean", mean)), tuple(cfg.get("image_std", std))
    return torch.tensor(mean).view(1, 3, 1, 1), torch.tensor(std).view(1, 3, 1, 1)


def _transformers() -> Any:
    try:
        import transformers
    except ImportError:
        raise NeoError(
            "CLIP / DINO backends need transformers: pip install 'neoedit[clip]'"
        ) from None
    return transformers


@functools.lru_cache(maxsize=2)
def load_clip(path: str) -> tuple[Any, Any, tuple[torch.Tensor, torch.Tensor]]:
    """(CLIPModel in eval mode, tokenizer, (mean, std) image normalisation (1,3,1,1))."""
    p = check_checkpoint(path, "CLIP")
    tf = _transformers()
    try:
        model = tf.CLIPModel.from_pretrained(str(p), local_files_only=True).eval()
        tokenizer = tf.AutoTokenizer.from_pretrained(str(p), local_files_only=True)
    except (OSError, ValueError) as e:
        raise NeoError(f"cannot load CLIP from {p}: {e}") from None
    return model, tokenizer, _normalisation(p, CLIP_MEAN, CLIP_STD)


@functools.lru_cache(maxsize=2)
def load_dino(path: str) -> tuple[Any, tuple[torch.Tensor, torch.Tensor]]:
    """(Dinov2Model in eval mode, (mean, std) image normalisation)."""
    p = check_checkpoint(path, "DINOv2")
    tf = _transformers()
    try:
        model = tf.Dinov2Model.from_pretrained(str(p), local_files_only=True).eval()
    except (OSError, ValueError) as e:
        raise NeoError(f"cannot load DINOv2 from {p}: {e}") from None
    return model, _normalisation(p, IMAGENET_MEAN, IMAGENET_STD)


def features_tensor(out: Any) -> torch.Tensor:
    """``get_*_features`` returns a tensor in some transformers versions, an output in others."""
    if torch.is_tensor(out):
        return out
    return out.pooler_output
