"""The compiled hash-grid kernel against the PyTorch reference: values and gradients."""

import pytest
import torch

from neoedit.fields.hashgrid import (
    HashGridConfig,
    HashGridEncoding,
    encode_torch,
    level_resolutions,
)


@pytest.mark.parametrize("features", [1, 2, 4, 8])  # the kernels loop over any F
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


def test_reused_gradient_buffers_never_overwrite_a_live_gradient():
    """The numba backward reuses table-gradient arrays no tensor holds any more: gradients
    accumulated over several backward passes, two encodings in one pass, and a pass after
    the gradient was dropped all equal the PyTorch reference."""
    cfg = HashGridConfig(
        n_levels=4, log2_hashmap_size=9, base_resolution=4, max_resolution=64, backend="numba"
    )
    gen = torch.Generator().manual_seed(0)
    a, b = HashGridEncoding(cfg, seed=1), HashGridEncoding(cfg, seed=2)
    xs = [torch.rand(500, 3, generator=gen) for _ in range(3)]
    ws = [torch.randn(500, cfg.output_dim, generator=gen) for _ in range(3)]

    def reference(enc, pairs):
        table = enc.table.detach().clone().requires_grad_(True)
        sum((encode_torch(x, table, enc.resolutions) * w).sum() for x, w in pairs).backward()
        return table.grad

    for _ in range(2):  # the second round runs on the arrays the first one left in the pool
        a.table.grad = b.table.grad = None
        # two encodings of one table shape in one backward pass
        ((a(xs[0]) * ws[0]).sum() + (b(xs[1]) * ws[1]).sum()).backward()
        torch.testing.assert_close(a.table.grad, reference(a, [(xs[0], ws[0])]))
        torch.testing.assert_close(b.table.grad, reference(b, [(xs[1], ws[1])]))
        # accumulation: a second pass adds to the live gradient
        (a(xs[2]) * ws[2]).sum().backward()
        expected = reference(a, [(xs[0], ws[0]), (xs[2], ws[2])])
        torch.testing.assert_close(a.table.grad, expected, rtol=1e-4, atol=1e-5)
        assert a.table.grad.data_ptr() != b.table.grad.data_ptr()
    # once no tensor holds them, the arrays are reused (no fresh 33 MB mapping per step)
    used = {a.table.grad.data_ptr(), b.table.grad.data_ptr()}
    a.table.grad = b.table.grad = None
    (a(xs[0]) * ws[0]).sum().backward()
    assert a.table.grad.data_ptr() in used
