"""The SAC benchmark's floor counts exactly the matrix products of an update: ours, with no
gradient that no optimizer uses and the critics' width-1 output layer as a weighted sum, and
stable-baselines3's, which also computes the critics' weight gradients in the actor's backward
pass (the 13% more arithmetic RESULTS.md states) and its output layer as products."""

from __future__ import annotations

from pathlib import Path
from types import ModuleType

import pytest
from benchmark_scripts import load_script

from sili_robots.agent.sac import SAC


@pytest.fixture(scope="module")
def bench() -> ModuleType:
    return load_script("bench_sac_speed")


def linear(rows: int, inp: int, out: int) -> int:
    return 2 * rows * inp * out


def critic_weight_grads(d: int, a: int, h: int, b: int) -> int:
    """FLOP of the twin critics' weight gradients, the actor's backward pass does not need."""
    return 2 * (linear(b, h, 1) + linear(b, h, h) + linear(b, d + a, h))


def update_flop(d: int, a: int, h: int, b: int, output_products: bool = True) -> int:
    """FLOP of the products of one SAC update as written in the paper's algorithm: targets,
    critics' forward and backward, actor's forward and backward through frozen critics. Without
    ``output_products`` the critics' width-1 output layer is left out (6 products per critic:
    3 forward passes, a weight gradient and 2 input gradients)."""
    actor = linear(b, d, h) + linear(b, h, h) + linear(b, h, 2 * a)
    critics = 2 * (linear(b, d + a, h) + linear(b, h, h) + linear(b, h, 1))
    critic_input_grads = 2 * (linear(b, h, 1) + linear(b, h, h) + linear(b, h, d + a))
    actor_backward = 2 * linear(b, h, 2 * a) + 2 * linear(b, h, h) + linear(b, d, h)
    targets = actor + critics
    critic_step = critics + critic_weight_grads(d, a, h, b) + critic_input_grads
    critic_step -= 2 * linear(b, h, d + a)  # the critics' own inputs need no gradient
    actor_step = actor + critics + critic_input_grads + actor_backward
    output = 0 if output_products else 2 * 6 * linear(b, h, 1)
    return targets + critic_step + actor_step - output


def test_floor_counts_every_product_of_our_update(bench: ModuleType) -> None:
    d, a, h, b, updates = 7, 2, 32, 16, 3
    sac = SAC(d, a, hidden=h)
    batches = bench.ours_batches(d, a, b, updates)

    def run() -> None:
        for batch in batches:
            sac.update(*batch)

    gflop = bench.product_gflop(run, updates)
    assert gflop * 1e9 == pytest.approx(update_flop(d, a, h, b, False), rel=1e-9)


def test_stable_baselines3_also_computes_critic_weight_grads(bench: ModuleType) -> None:
    pytest.importorskip("stable_baselines3")
    d, a, b = 23, 2, 256
    gflop = bench.update_gflop(d, a, b)
    ours, sb3 = gflop["ours"], gflop["sb3"]
    assert ours * 1e9 == pytest.approx(update_flop(d, a, 256, b, False), rel=1e-9)
    extra = critic_weight_grads(d, a, 256, b)
    assert sb3 * 1e9 == pytest.approx(update_flop(d, a, 256, b) + extra, rel=1e-9)


def latent_update_flop(o: int, a: int, k: int, h: int, n: int, horizon: int) -> int:
    """FLOP of the products of one latent-model update: the encoder's per-step MLP on the
    previous interactions' transitions and its head on the mean and max pools, the discrete
    decoder's k heads on the current ones; backward, the weight gradients of every layer and
    the input gradients of every layer but each network's first (its input is data)."""
    rows = n * horizon
    forward = (
        linear(rows, 2 * o + a + 1, h)
        + linear(rows, h, h)
        + linear(n, 2 * h, k)
        + linear(rows, o + a, h)
        + linear(rows, h, h)
        + linear(rows, h, k * (o + 1))
    )
    input_grads = linear(rows, h, h) + linear(n, 2 * h, k) + linear(rows, h, h)
    input_grads += linear(rows, h, k * (o + 1))
    return 2 * forward + input_grads


def test_floor_counts_every_product_of_a_latent_update(bench: ModuleType) -> None:
    from sili_robots.agent.config import AgentConfig

    cfg = AgentConfig()
    step = bench.latent_step(3, 2, 7)
    gflop = bench.product_gflop(lambda: [step() for _ in range(2)], 2)
    flop = latent_update_flop(3, 2, cfg.model.dim, cfg.hidden, cfg.model.batch, 7)
    assert gflop * 1e9 == pytest.approx(flop, rel=1e-9)


def test_stable_baselines3_reference_leaves_no_log_folder(
    bench: ModuleType, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """stable-baselines3 makes an empty SB3-<time> folder in the temporary directory for a model
    without a logger; the benchmark's reference, built once per round, must not litter it."""
    pytest.importorskip("stable_baselines3")
    import tempfile

    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    bench.make_sb3(5, 2, 16)
    assert list(tmp_path.iterdir()) == []
