"""The networks' layers: the twin critic's output layer (a weighted sum, the same function and
gradients as the batched product it replaces, with no matrix product left in it: those ran
5-20x slower), the ensemble layers' bias, and the actor's tanh-squashed Gaussian."""

import math

import pytest
import torch
from torch.distributions import Normal

from sili_robots.agent.networks import Actor, EnsembleLinear

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


def test_the_actor_samples_a_tanh_squashed_gaussian_with_its_exact_log_probability():
    torch.manual_seed(0)
    actor = Actor(4, 3, 32)
    with torch.no_grad():
        actor.head.bias[3:].fill_(1.0)  # std far from 1, so std * eps and eps differ
    x = torch.randn(256, 4)
    with torch.no_grad():
        mean, log_std = actor(x)
        torch.manual_seed(1)
        action, logp = actor.sample(x)
        torch.manual_seed(1)
        eps = torch.randn_like(mean)
    pre = mean + log_std.exp() * eps
    torch.testing.assert_close(action, torch.tanh(pre))
    p = pre.double()  # the reference in float64: log(1 - tanh^2) loses float32's digits
    ref = Normal(mean.double(), log_std.double().exp()).log_prob(p).sum(-1)
    ref = ref - torch.log1p(-torch.tanh(p).pow(2)).sum(-1)
    torch.testing.assert_close(logp.double(), ref, rtol=1e-4, atol=1e-4)
    assert math.isfinite(float(logp.sum()))


def test_a_wide_ensemble_layer_on_aten_is_the_batched_product_plus_its_bias():
    torch.manual_seed(0)
    layer = EnsembleLinear(2, 8, 16, matmul="aten")
    with torch.no_grad():
        layer.bias.fill_(3.0)
    x = torch.randn(2, 32, 8)
    with torch.no_grad():
        torch.testing.assert_close(layer(x), torch.baddbmm(layer.bias, x, layer.weight))
