"""LERF relevancy of language features to a query against canonical negative phrases.

relevancy(x) = min_i  exp(f.q) / (exp(f.q) + exp(f.c_i))   (Kerr et al. 2023, eq. 1)

with f the feature at x, q the query embedding and c_i the canonical phrases ("object",
"things", "stuff", "texture"). 0.5 means "no more related to the query than to a generic
phrase"; a relevancy above 0.5 against every canonical phrase is needed for a match.
"""

from __future__ import annotations

import torch

CANONICAL_PHRASES = ("object", "things", "stuff", "texture")


def relevancy(
    features: torch.Tensor, query: torch.Tensor, canonical: torch.Tensor, temperature: float = 1.0
) -> torch.Tensor:
    """features (N,D), query (D,), canonical (C,D) embeddings -> relevancy (N,) in (0,1).

    The pairwise softmax exp(a)/(exp(a)+exp(b)) equals sigmoid(a - b).
    """
    sim_q = features @ query / temperature  # (N,)
    sim_c = features @ canonical.T / temperature  # (N, C)
    return torch.sigmoid(sim_q[:, None] - sim_c).min(dim=-1).values


def split_prompts(text: str) -> list[str]:
    """'red mug; duck' -> ['red mug', 'duck'] (empty parts dropped)."""
    return [p.strip() for p in text.split(";") if p.strip()]
