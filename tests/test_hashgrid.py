"""The compiled hash-grid kernel against the PyTorch reference: values and gradients."""

import pytest
import torch

from neoedit.fields.hashgrid import (
    HashGridConfig,
    HashGridEncoding,
    encode_torch,
    level_resolutions,
)


@pytest.mark.parametrize("features", [1, 2, 4])
def test_numba_matches_torch(features):
    # small table: coarse levels are dense, fine levels are hashed
    cfg = HashGridConfig(
        n_levels=6,
        features_per_level=features,
        log2_hashmap_size=10,
        base_resolution=4,
        max_resolution=128,
        backend="numba",
    )
    enc = HashGridEncoding(cfg, seed=3)
    with torch.no_grad():
        enc.table.normal_()
    x = torch.rand(3000, 3, generator=torch.Generator().manual_seed(0))
    x[:4] = torch.tensor([[0.0, 0.0, 0.0], [1.0, 1.0, 1.0], [1.0, 0.0, 0.5], [0.999999, 0.5, 0.0]])
    grad = torch.randn(3000, cfg.output_dim, generator=torch.Generator().manual_seed(1))

    y_fast = enc(x)
    (y_fast * grad).sum().backward()
    g_fast = enc.table.grad.clone()
    enc.table.grad = None
    y_ref = encode_torch(x, enc.table, enc.resolutions)
    (y_ref * grad).sum().backward()

    torch.testing.assert_close(
        y_fast, y_ref, rtol=1e-4, atol=5e-5
    )  # float32, other summation order
    torch.testing.assert_close(g_fast, enc.table.grad, rtol=1e-4, atol=1e-4)
    assert g_fast.abs().sum() > 0


def test_levels_and_dense_indexing():
    cfg = HashGridConfig(n_levels=4, base_resolution=4, max_resolution=32, log2_hashmap_size=12)
    assert level_resolutions(cfg) == [4, 8, 16, 32]
    enc = HashGridEncoding(dataclass_replace(cfg, backend="torch"))
    # a dense level is exactly trilinear: at a grid vertex the feature is that vertex's row
    x = torch.tensor([[0.25, 0.5, 0.75]])  # vertex (1, 2, 3) at resolution 4
    side = 5
    row = 1 + 2 * side + 3 * side * side
    out = enc(x)
    torch.testing.assert_close(out[0, :2], enc.table[0, row])


def test_empty_input():
    enc = HashGridEncoding(HashGridConfig(log2_hashmap_size=10))
    assert enc(torch.zeros(0, 3)).shape == (0, enc.output_dim)


def dataclass_replace(cfg, **kw):
    import dataclasses

    return dataclasses.replace(cfg, **kw)
