"""The twin critic's output layer: a weighted sum, the same function and gradients as the
batched product it replaces, with no matrix product left in it (those ran 5-20x slower)."""

import pytest
import torch

from sili_robots.agent.networks import EnsembleLinear

PRODUCTS = {"aten::bmm", "aten::baddbmm", "aten::mm", "aten::addmm", "mkldnn::_linear_pointwise"}


@pytest.mark.parametrize("matmul", ["aten", "onednn"])
def test_width_one_ensemble_layer_is_the_batched_product_without_one(matmul):
    torch.manual_seed(0)
    layer = EnsembleLinear(2, 64, 1, matmul=matmul)
    base = torch.randn(128, 64, requires_grad=True)
    x = base.unsqueeze(0).expand(2, -1, -1)  # as the critic feeds it: one input, expanded
    grad = torch.randn(2, 128, 1)
    params = (base, layer.weight, layer.bias)
    want = torch.baddbmm(layer.bias, x, layer.weight)
    want_grads = torch.autograd.grad(want, params, grad)
    with torch.profiler.profile() as prof:
        got = layer(x)
        got_grads = torch.autograd.grad(got, params, grad)
    assert not PRODUCTS & {e.key for e in prof.key_averages()}
    for g, w in zip((got, *got_grads), (want, *want_grads), strict=True):
        torch.testing.assert_close(g, w, rtol=1e-5, atol=1e-5 * float(w.detach().abs().max()))
