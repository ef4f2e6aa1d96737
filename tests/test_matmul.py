"""Linear layers on oneDNN: the same float32 function and gradients as PyTorch's default path."""

import pytest
import torch
import torch.nn.functional as F
from torch.profiler import profile

from sili_robots.agent import AgentConfig, SILIAgent, method_config
from sili_robots.agent.latent import LatentModel
from sili_robots.agent.matmul import MIN_WIDTH, default_matmul, linear, onednn_available
from sili_robots.agent.networks import EnsembleLinear
from sili_robots.agent.sac import SAC
from sili_robots.errors import ConfigError
from sili_robots.migrations import migrate_run

pytestmark = pytest.mark.skipif(not onednn_available(), reason="PyTorch without oneDNN")


def _close(a: torch.Tensor, b: torch.Tensor) -> None:
    """float32 rounding apart, not more (another summation order, the same arithmetic)."""
    torch.testing.assert_close(a, b, rtol=1e-5, atol=1e-5 * float(b.detach().abs().max()))


def _ops(fn) -> set[str]:
    with profile() as prof:
        fn()
    return {e.key for e in prof.key_averages()}


@pytest.mark.parametrize("shape", [(64, 20), (4, 16, 20)])
@pytest.mark.parametrize("out", [MIN_WIDTH, 17, 48])  # narrower ones take aten (test below)
def test_linear_matches_aten_forward_and_backward(shape, out):
    torch.manual_seed(0)
    x = torch.randn(*shape, requires_grad=True)
    w = torch.randn(out, 20, requires_grad=True)
    b = torch.randn(out, requires_grad=True)
    grad = torch.randn(*shape[:-1], out)
    ref = F.linear(x, w, b)
    ref_grads = torch.autograd.grad(ref, (x, w, b), grad)
    y = linear(x, w, b, "onednn")
    grads = torch.autograd.grad(y, (x, w, b), grad)
    _close(y, ref)
    for g, r in zip(grads, ref_grads, strict=True):
        _close(g, r)


def test_wide_layers_run_on_onednn_and_narrow_ones_do_not():
    x, b = torch.randn(32, 20), torch.randn(MIN_WIDTH)
    wide, narrow = torch.randn(MIN_WIDTH, 20), torch.randn(MIN_WIDTH - 1, 20)
    assert "mkldnn::_linear_pointwise" in _ops(lambda: linear(x, wide, b, "onednn"))
    assert "mkldnn::_linear_pointwise" not in _ops(lambda: linear(x, wide, b, "aten"))
    assert "mkldnn::_linear_pointwise" not in _ops(lambda: linear(x, narrow, b[:-1], "onednn"))


@pytest.mark.parametrize("out", [MIN_WIDTH, 32])  # width 1 is a weighted sum, no product
def test_ensemble_layer_matches_the_batched_aten_layer(out):
    torch.manual_seed(0)
    ref = EnsembleLinear(2, 20, out, matmul="aten")
    dnn = EnsembleLinear(2, 20, out, matmul="onednn")
    dnn.load_state_dict(ref.state_dict())
    # the critic feeds both members one input, expanded: its gradient sums over them
    base = torch.randn(64, 20, requires_grad=True)
    grad = torch.randn(2, 64, out)
    results = []
    for layer in (ref, dnn):
        y = layer(base.unsqueeze(0).expand(2, -1, -1))
        results.append((y, *torch.autograd.grad(y, (base, layer.weight, layer.bias), grad)))
    for got, want in zip(results[1], results[0], strict=True):
        _close(got, want)


def test_sac_gradients_match_between_kernel_libraries():
    """One critic loss and its gradients, from the same weights and batch, on both paths."""
    torch.manual_seed(0)
    aten, dnn = SAC(7, 2, hidden=64, matmul="aten"), SAC(7, 2, hidden=64, matmul="onednn")
    dnn.critic.load_state_dict(aten.critic.state_dict())
    dnn.critic_target.load_state_dict(aten.critic_target.state_dict())
    x, a, r, x2 = (
        torch.randn(128, 7),
        torch.rand(128, 2) * 2 - 1,
        torch.randn(128),
        torch.randn(128, 7),
    )
    a2, logp2 = torch.rand(128, 2) * 2 - 1, torch.randn(128)
    losses, grads = [], []
    for sac in (aten, dnn):
        loss = sac.critic_loss(x, a, r, x2, a2, logp2)
        losses.append(loss)
        grads.append(torch.autograd.grad(loss, list(sac.critic.parameters())))
    _close(losses[1], losses[0])
    for g1, g0 in zip(grads[1], grads[0], strict=True):
        _close(g1, g0)


def test_onednn_sac_update_runs_its_products_on_onednn():
    sac = SAC(5, 2, hidden=64, matmul="onednn")
    x, a, r = torch.randn(128, 5), torch.rand(128, 2) * 2 - 1, torch.randn(128)
    assert "mkldnn::_linear_pointwise" in _ops(lambda: sac.update(x, a, r, x))
    assert "mkldnn::_linear_pointwise" not in _ops(lambda: SAC(5, 2, hidden=64).update(x, a, r, x))


def test_latent_model_loss_and_gradients_match_between_kernel_libraries():
    torch.manual_seed(0)
    ref = LatentModel(3, 2, 4, 32, "discrete", matmul="aten")
    dnn = LatentModel(3, 2, 4, 32, "discrete", matmul="onednn")
    dnn.load_state_dict(ref.state_dict())
    prev, obs = torch.randn(8, 5, 9), torch.randn(8, 5, 3)
    act, nxt, rew = torch.randn(8, 5, 2), torch.randn(8, 5, 3), torch.randn(8, 5)
    out = []
    for model in (ref, dnn):
        loss = model.loss(prev, obs, act, nxt, rew)
        out.append((loss, *torch.autograd.grad(loss, list(model.parameters()))))
    for got, want in zip(out[1], out[0], strict=True):
        _close(got, want)


@pytest.mark.parametrize("faster", ["aten", "onednn"])
def test_matmul_defaults_to_the_library_timed_faster(faster, tmp_path, monkeypatch):
    """Chosen by a timing once per machine and cached (the two are within a few percent on some
    machines, so the real timing may pick either)."""
    from sili_robots.agent import matmul

    monkeypatch.setenv("SILI_ROBOTS_CACHE", str(tmp_path))
    times = {"aten": 2.0, "onednn": 2.0, faster: 1.0}
    monkeypatch.setattr(matmul, "time_matmuls", lambda: times)
    assert default_matmul() == faster
    monkeypatch.setattr(matmul, "time_matmuls", lambda: pytest.fail("timed twice"))
    assert default_matmul() == faster  # from the cache
    assert method_config("sili").matmul == faster


def test_matmul_setting_runs_onednn_and_old_runs_keep_aten(tmp_path, monkeypatch):
    from sili_robots.agent import matmul

    monkeypatch.setenv("SILI_ROBOTS_CACHE", str(tmp_path))
    monkeypatch.setattr(matmul, "time_matmuls", lambda: {"aten": 2.0, "onednn": 1.0})
    cfg = method_config("sili")
    assert cfg.matmul == "onednn"
    agent = SILIAgent(cfg, obs_dim=3, act_dim=2, horizon=5, strategy_dim=2)
    assert agent.sac.actor.trunk[0].matmul == "onednn"
    assert agent.model.phi[0].matmul == "onednn"
    # a config.json written before the setting existed (settings flat, no matmul)
    saved = {"method": "sili", "latent": "discrete", "latent_dim": 10, "hidden": 256}
    assert AgentConfig.from_dict(migrate_run({"agent": saved})["agent"]).matmul == "aten"
    assert method_config("sili", overrides={"matmul": "aten"}).matmul == "aten"
    with pytest.raises(ConfigError, match="unknown matmul 'mkl'; allowed: onednn, aten"):
        method_config("sili", overrides={"matmul": "mkl"})
