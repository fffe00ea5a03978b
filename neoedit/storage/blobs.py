"""Tensor groups as content-addressed blobs, in full or as sparse deltas.

An edit changes a small part of a scene's weights: the rows of a hash table its samples
read, a few occupancy cells, the language field near the edit. A version inside a store is
therefore written as, per tensor, one of

* ``same``: bit-identical to a tensor of the parent version (nothing stored);
* ``delta``: the parent's tensor plus a sparse change — a packed bit mask of the changed
  elements and their changes at half precision (exact float32 when a change exceeds half
  precision's range). The change is rounded *before* it is stored and the version is
  exactly what the blob reconstructs (``parent + half(change)``), so loading it again is
  bit-identical. The rounding error is below 1/2048 of each change;
* ``rows``: the parent's rows kept (a packed mask) followed by new rows (a query point
  cloud after an edit drops the points in the edited boxes and appends re-rendered ones);
* ``full``: the tensor itself (new tensors, integer tensors, and whenever the delta would
  not be at least twice smaller).

A blob is one safetensors file (the tensors of one group), zlib-compressed, named by the
SHA-256 of its uncompressed bytes; identical blobs are stored once.
"""

from __future__ import annotations

import hashlib
import zlib
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import torch
from safetensors.torch import load, save

from neoedit.errors import NeoError
from neoedit.utils.io import atomic_write_bytes

DELTA_MAX_SHARE = 0.5
"""A delta is stored only when it takes at most this share of the full tensor's bytes."""


def _delta(x: torch.Tensor, ref: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor] | None:
    """(packed mask uint8, changed values) such that :func:`_apply` gives back the stored
    version of ``x``; None when a delta does not pay. Changes are kept at half precision,
    or exactly (float32) when some exceed half precision's range (densities can)."""
    change = (x.float() - ref.float()).reshape(-1)
    half = change.half()
    if bool(torch.isfinite(half).all()):
        change = half
    changed = change != 0
    k = int(changed.sum())
    if x.numel() / 8 + change.element_size() * k > DELTA_MAX_SHARE * x.numel() * x.element_size():
        return None
    mask = torch.from_numpy(np.packbits(changed.numpy()))
    return mask, change[changed].contiguous()


def _apply(ref: torch.Tensor, mask: torch.Tensor, values: torch.Tensor) -> torch.Tensor:
    changed = torch.from_numpy(np.unpackbits(mask.numpy(), count=ref.numel()).astype(bool))
    out = ref.reshape(-1).clone()
    out[changed] = (ref.reshape(-1)[changed].float() + values.float()).to(ref.dtype)
    return out.reshape(ref.shape)


def _rows(x: torch.Tensor, ref: torch.Tensor) -> torch.Tensor | None:
    """The packed mask of ``ref``'s rows that ``x`` starts with, in order, when ``x`` is
    ``ref[mask]`` followed by new rows (a query cloud after an edit); None otherwise."""
    if x.dim() != 2 or ref.dim() != 2 or x.shape[1] != ref.shape[1] or x.dtype != ref.dtype:
        return None
    as_rows = np.dtype((np.void, x.shape[1] * x.element_size()))
    xr = np.ascontiguousarray(x.numpy()).view(as_rows).ravel()
    rr = np.ascontiguousarray(ref.numpy()).view(as_rows).ravel()
    keep = np.isin(rr, xr)
    n = int(keep.sum())
    if n == 0 or n > len(xr) or not np.array_equal(xr[:n], rr[keep]):
        return None
    return torch.from_numpy(np.packbits(keep))


def _candidates(name: str, parent: Mapping[str, torch.Tensor]) -> list[str]:
    """Parent tensors a tensor may be stored against: its own name first, then (for a new
    patch) the same parameter of the base field and of every earlier patch (a carried
    part's ``patchN.field.X`` matches the base's ``field.X``)."""
    if name in parent:
        return [name]
    suffix = name.split(".", 1)[1] if "." in name else name
    same = {suffix, suffix.removeprefix("field.")}
    return [k for k in parent if k != name and k.split(".", 1)[-1] in same]


def encode(
    tensors: Mapping[str, torch.Tensor], parent: Mapping[str, torch.Tensor] | None
) -> tuple[dict[str, torch.Tensor], dict[str, dict[str, Any]], dict[str, torch.Tensor]]:
    """(payload, entries, stored): the blob's tensors, the manifest entry of every tensor,
    and every tensor as it will load (a delta's rounding applied)."""
    payload: dict[str, torch.Tensor] = {}
    entries: dict[str, dict[str, Any]] = {}
    stored: dict[str, torch.Tensor] = {}
    for name, t in tensors.items():
        t = t.detach().cpu().contiguous().clone()  # never a live parameter's storage
        best: tuple[int, str, Any] | None = None
        floating = t.is_floating_point() and t.dtype != torch.float16
        for ref_name in _candidates(name, parent or {}) if parent is not None else []:
            ref = parent[ref_name]  # type: ignore[index]
            if ref.shape != t.shape or ref.dtype != t.dtype:
                continue
            if torch.equal(ref, t):
                best = (0, ref_name, None)
                break
            d = _delta(t, ref) if floating else None
            if d is not None and (best is None or d[1].numel() < best[0]):
                best = (d[1].numel(), ref_name, d)
        rows = _rows(t, parent[name]) if parent is not None and name in parent else None
        if best is None and rows is not None:
            ref = parent[name]  # type: ignore[index]
            n = int(np.unpackbits(rows.numpy(), count=len(ref)).sum())
            payload[f"rows/{name}"], payload[f"new/{name}"] = rows, t[n:].contiguous()
            entries[name] = {"enc": "rows", "ref": name}
            stored[name] = t
        elif best is None:
            payload[f"full/{name}"] = t
            entries[name] = {"enc": "full"}
            stored[name] = t
        elif best[2] is None:
            entries[name] = {"enc": "same", "ref": best[1]}
            stored[name] = parent[best[1]]  # type: ignore[index]
        else:
            mask, values = best[2]
            payload[f"mask/{name}"], payload[f"values/{name}"] = mask, values
            entries[name] = {"enc": "delta", "ref": best[1]}
            stored[name] = _apply(parent[best[1]], mask, values)  # type: ignore[index]
    return payload, entries, stored


def decode(
    payload: Mapping[str, torch.Tensor],
    entries: Mapping[str, Mapping[str, Any]],
    parent: Mapping[str, torch.Tensor] | None,
    where: str,
) -> dict[str, torch.Tensor]:
    """The tensors of a manifest group from its blob's payload and the parent's tensors."""
    out: dict[str, torch.Tensor] = {}
    for name, e in entries.items():
        enc = e.get("enc")
        try:
            if enc == "full":
                out[name] = payload[f"full/{name}"]
                continue
            if parent is None:
                raise KeyError("the parent version")
            ref = parent[e["ref"]]
            if enc == "same":
                out[name] = ref
            elif enc == "delta":
                out[name] = _apply(ref, payload[f"mask/{name}"], payload[f"values/{name}"])
            elif enc == "rows":
                keep = np.unpackbits(payload[f"rows/{name}"].numpy(), count=len(ref)).astype(bool)
                out[name] = torch.cat([ref[torch.from_numpy(keep)], payload[f"new/{name}"]])
            else:
                raise NeoError(f"{where}: unknown tensor encoding {enc!r} for {name}")
        except KeyError as missing:
            raise NeoError(f"{where}: cannot rebuild {name}: {missing} is missing") from None
    return out


def put_blob(folder: Path, payload: Mapping[str, torch.Tensor]) -> tuple[str, int]:
    """Write ``payload`` as a blob under ``folder`` (once per content); (digest, bytes on
    disk)."""
    raw = save(dict(payload)) if payload else b""
    digest = hashlib.sha256(raw).hexdigest()
    path = Path(folder) / f"{digest}.st.z"
    if not path.is_file():
        atomic_write_bytes(path, zlib.compress(raw, 1))
    return digest, path.stat().st_size


def get_blob(folder: Path, digest: str) -> dict[str, torch.Tensor]:
    path = Path(folder) / f"{digest}.st.z"
    try:
        raw = zlib.decompress(path.read_bytes())
    except FileNotFoundError:
        raise NeoError(f"{path}: blob missing (the store is incomplete)") from None
    except (OSError, zlib.error) as e:
        raise NeoError(f"{path}: cannot read blob: {e}") from None
    if hashlib.sha256(raw).hexdigest() != digest:
        raise NeoError(f"{path}: blob is corrupt (its content does not match its name)")
    return dict(load(raw)) if raw else {}
