"""The SILI agent's pieces, each checked against what it must do."""

import copy
import io
import subprocess
import sys

import numpy as np
import pytest
import torch
from agent_helpers import make_agent, run_config

from sili_robots.addons.last_step import last_transition
from sili_robots.addons.latent_filter import LatentFilter, largest_power_of_two
from sili_robots.addons.posteriors import HindsightPosteriors
from sili_robots.agent import AgentConfig, Schedule, SILIAgent
from sili_robots.agent.buffer import KEYS
from sili_robots.agent.latent import (
    LatentModel,
    category_groups,
    decoder_targets,
    gumbel_straight_through,
    target_scale,
    transitions,
)
from sili_robots.agent.matmul import onednn_available
from sili_robots.agent.sac import SAC
from sili_robots.build import make_run_config
from sili_robots.errors import ConfigError
from sili_robots.migrations import migrate_run

H = 5


def _agent(method="sili", latent=None, **kw):
    settings = {"latent_dim": 4, "hidden": 32, "batch_interactions": 4, "batch_steps": H, **kw}
    return make_agent(method, latent, horizon=H, **settings)


def method_config(method="sili", latent=None, **settings):
    """The agent config of a method with settings by their flat names."""
    return run_config(method, latent, **settings).agent


def _posteriors(agent):
    return agent.addon(HindsightPosteriors)


def _fill(agent, n, flags=None):
    rng = np.random.default_rng(1)
    for j in range(n):
        obs = rng.normal(size=(H + 1, 3)).astype(np.float32)
        nxt = rng.normal(size=3).astype(np.float32)
        if flags is not None:
            obs[:, -1], nxt[-1] = flags[j][:-1], flags[j][-1]
        agent.observe_interaction(
            obs,
            rng.uniform(-1, 1, (H, 2)).astype(np.float32),
            rng.normal(size=H).astype(np.float32),
            nxt,
            float(j % 2),
            {"strategy": np.array([(j + 1) % 2, 0], np.float32)},
        )


def test_gumbel_straight_through_is_one_hot_forward_with_gradients_backward():
    logits = torch.randn(64, 10, requires_grad=True)
    z = gumbel_straight_through(logits)
    assert torch.all((z == 0) | (z == 1)) and torch.all(z.sum(-1) == 1)
    (z * torch.arange(10.0)).sum().backward()
    assert logits.grad is not None and logits.grad.abs().sum() > 0


def test_discrete_stability_reward_is_minus_one_on_category_change_at_last_step():
    agent = _agent()
    _fill(agent, 6)
    agent.Z = np.eye(4, dtype=np.float32)[[0, 1, 1, 2, 2, 2, 3]]  # z^0..z^6
    j = np.array([[1], [2], [3], [4], [0]])
    t = np.full((5, 1), H - 1)
    r = agent._stability_rewards(j, t, t == H - 1, np.zeros((5, 1, 3)))
    scale = agent.stability_scale
    # z^1->z^2 same (0), z^2->z^3 change (-1), z^3->z^4 same, z^4->z^5 same, j=0: no history
    np.testing.assert_allclose(r[:, 0], [0, -scale, 0, 0, 0])
    mid = agent._stability_rewards(j, t - 1, t - 1 == H - 1, np.zeros((5, 1, 3)))
    assert np.all(mid == 0)  # credited only on the step that crosses into the next interaction


def test_continuous_stability_reward_is_euclidean():
    agent = _agent(latent="continuous")
    _fill(agent, 3)
    agent.Z = np.array([[0, 0, 0, 0], [1, 0, 0, 0], [1, 3, 4, 0], [1, 3, 4, 0]], np.float32)
    j = np.array([[1], [2]])
    t = np.full((2, 1), H - 1)
    r = agent._stability_rewards(j, t, t == H - 1, np.zeros((2, 1, 3)))
    np.testing.assert_allclose(r[:, 0], [-5 * agent.stability_scale, 0])


def test_partial_stability_reward_is_the_observed_flag_each_step():
    agent = _agent(latent="partial")
    flags = [np.array([0, 1, 0, 0, 1, 0, 1], np.float32)] * 3  # obs_0..obs_H, next_first
    _fill(agent, 3, flags)
    x, _, r, x2 = agent.sample_batches(1, beta=1.0)
    # reward = -flag of the next observation, whatever the step
    np.testing.assert_allclose(r[0].numpy(), -x2[0, :, 2].numpy())
    assert agent.n_latents == 0 and x.shape[-1] == 3
    stats = agent._stats(0, np.array([0, 0, 1], np.float32), {})
    assert stats.stability_reward == -3.0  # flags at t=2, t=5 and the boundary


def test_the_reward_is_the_b_weighted_sum_of_task_and_stability_rewards():
    """R = (1 - b) R_task + b R_stable, on the same sampled transitions."""
    agent = _agent(latent="partial")
    _fill(agent, 3, [np.array([0, 1, 0, 0, 1, 0, 1], np.float32)] * 3)
    state = agent.rng.bit_generator.state
    rewards = {}
    for beta in (0.0, 1.0, 0.3):
        agent.rng.bit_generator.state = state  # the same transitions each time
        rewards[beta] = agent.sample_batches(2, beta=beta)[2].numpy()
    task, stable = rewards[0.0], rewards[1.0]
    assert np.abs(task).sum() > 0 and np.abs(stable).sum() > 0 and not np.allclose(task, stable)
    np.testing.assert_allclose(rewards[0.3], 0.7 * task + 0.3 * stable, rtol=1e-6, atol=1e-7)


def test_the_logged_latent_change_is_a_change_of_category():
    """``latent_changed`` (metrics.csv, the summary's change agreement): z^j's category against
    z^{j+1}'s; the game's first interaction has no z^{j} to compare."""
    agent = _agent()
    _fill(agent, 4)
    agent.Z = np.eye(4, dtype=np.float32)[[0, 1, 1, 2, 2]]
    stats = [agent._stats(j, np.zeros(3, np.float32), {}) for j in range(4)]
    assert [s.latent_changed for s in stats] == [False, False, True, False]
    assert [s.latent_category for s in stats] == [1, 1, 2, 2]


def test_true_latent_mode_uses_the_true_strategy():
    agent = _agent(latent="true")
    agent.begin_game({"strategy": np.array([0, 0], np.float32)})
    _fill(agent, 4)
    assert agent.zdim == 2
    np.testing.assert_array_equal(agent.Z[1:, 0], [1, 0, 1, 0])
    # R_stable's d is whether the true strategy changed, also after interaction 0 (z^0 is the
    # strategy the game began with, not "no history"), however small the change
    agent.Z[:, 0] = [0.0, 1.0, 1.0, 1.001, 1.001]
    np.testing.assert_array_equal(agent.change_after(np.arange(4)), [1, 0, 1, 0])


def test_bootstrap_across_boundary_uses_next_interactions_latents_and_first_obs():
    agent = _agent()
    _fill(agent, 6)
    agent.Z = np.eye(4, dtype=np.float32)[[0, 1, 2, 3, 0, 1, 2]]
    x, _, _, x2 = agent.sample_batches(50, beta=0.5)
    x, x2 = x.reshape(-1, x.shape[-1]).numpy(), x2.reshape(-1, x2.shape[-1]).numpy()
    b = agent.buffer
    hits = 0
    for row, row2 in zip(x, x2, strict=True):
        match = np.where((b.obs[:, :-1] == row[:3]).all(-1))
        j, t = int(match[0][0]), int(match[1][0])
        np.testing.assert_array_equal(row[3:7], agent.Z[j])  # z^j
        if t == H - 1:
            hits += 1
            np.testing.assert_array_equal(row2[:3], b.next_first[j])
            np.testing.assert_array_equal(row2[3:7], agent.Z[j + 1])  # z^{j+1}
            np.testing.assert_array_equal(row2[7:11], agent.Z[j])  # z^j as the previous one
        else:
            np.testing.assert_array_equal(row2[:3], b.obs[j, t + 1])
            np.testing.assert_array_equal(row2[3:7], agent.Z[j])
    assert hits > 0


def _sampled_interactions(agent, n_updates):
    """The replay index of every interaction in each sampled batch, found by its observations."""
    x, _, _, _ = agent.sample_batches(n_updates, beta=0.0)
    rows = x[..., :3].numpy().reshape(n_updates, agent.cfg.sac.batch_interactions, -1, 3)
    obs = agent.buffer.obs[: agent.buffer.n, :-1]
    return np.array([[np.where((obs == r[0]).all(-1))[0][0] for r in batch] for batch in rows])


def test_recent_fraction_draws_that_part_of_each_batch_from_the_newest_interactions():
    uniform = _agent(method="lili")
    _fill(uniform, 40)
    assert (_sampled_interactions(uniform, 50) < 30).mean() > 0.5  # 3/4 of draws, uniformly
    recent = _agent(method="lili", recent_fraction=0.5, recent_interactions=10)
    _fill(recent, 40)
    j = _sampled_interactions(recent, 50)  # 4 interactions per batch: 2 recent, 2 uniform
    assert (j[:, :2] >= 30).all()
    assert (j[:, 2:] < 30).mean() > 0.5
    with pytest.raises(ConfigError, match=r"addons.recent.fraction must be in \[0, 1\], got 2"):
        method_config("sili", recent_fraction=2.0)


def test_change_pairs_are_where_the_sure_posterior_category_changes():
    agent = _agent(latent_change_fraction=0.25)
    post = _posteriors(agent)
    assert not post.replaces_distance
    _fill(agent, 6)
    assert len(post.P) == 6  # kept for every stored interaction
    sure, flat = np.eye(4, dtype=np.float32), np.full(4, 0.25, np.float32)
    post.P = np.stack([sure[0], sure[0], sure[1], flat, sure[2], sure[2]])
    # 1 -> 2 changed; 2 -> 3 and 3 -> 4 involve an interaction that cannot tell (flat)
    np.testing.assert_array_equal(post.change_pairs(), [2])
    half = np.array([0.0, 0.5, 0.25, 0.25], np.float32)  # exactly 0.5 on its category: sure
    post.P = np.stack([sure[0], half, sure[1], flat, sure[2], sure[2]])
    np.testing.assert_array_equal(post.change_pairs(), [1])
    with pytest.raises(ConfigError, match=r"change_fraction must be in \[0, 1\], got -1"):
        method_config("sili", latent_change_fraction=-1.0)


def test_latent_change_fraction_draws_that_part_of_each_latent_batch_from_change_pairs():
    agent = _agent(latent_change_fraction=0.5, latent_batch=8)
    _fill(agent, 20)
    _posteriors(agent).P = np.eye(4, dtype=np.float32)[[0] * 10 + [1] * 10]  # one change: j = 10
    prevs = []
    loss = agent.model.loss

    def spy(prev, *args):
        prevs.append(prev[:, 0, :3].numpy().copy())  # first s of tau^{j-1}
        return loss(prev, *args)

    agent.model.loss = spy
    agent.update_latent_model(20)
    first_obs = agent.buffer.obs[:20, 0]
    j = np.array([[np.where((first_obs == r).all(-1))[0][0] + 1 for r in p] for p in prevs])
    assert (j[:, :4] == 10).all()  # half of each batch: the change pair (9, 10)
    assert (j[:, 4:] != 10).mean() > 0.8  # the rest uniform over 1..19


@pytest.mark.parametrize(
    "precision,matmul", [("float32", "aten"), ("float32", "onednn"), ("bfloat16", "aten")]
)
def test_one_sac_update_lowers_critic_loss_on_a_fixed_batch(precision, matmul):
    if matmul == "onednn" and not onednn_available():
        pytest.skip("PyTorch without oneDNN")
    torch.manual_seed(0)
    sac = SAC(5, 2, hidden=64, lr=1e-3, precision=precision, matmul=matmul)
    x, a, r, x2 = (
        torch.randn(128, 5),
        torch.rand(128, 2) * 2 - 1,
        torch.randn(128),
        torch.randn(128, 5),
    )
    with torch.no_grad():
        a2, logp2 = sac.actor.sample(x2)
    before = float(sac.critic_loss(x, a, r, x2, a2, logp2).detach())
    out = sac.update(x, a, r, x2)
    after = float(sac.critic_loss(x, a, r, x2, a2, logp2).detach())
    assert after < before
    # whatever the precision of the matrix products, what is learned and reported is float32
    assert out["critic_loss"].dtype == torch.float32
    assert all(p.dtype == torch.float32 for p in sac.critic.parameters())
    assert sac.actor.sample(x)[1].dtype == torch.float32


def test_acting_draws_the_sampled_action_and_an_update_leaves_the_critics_trainable():
    """``act`` skips the log-probability, not the draw: the action ``sample`` gives from the same
    random state. The update freezes the critics for the actor's step on their parameter list:
    afterwards they train again, and the next critic step starts from fresh gradients."""
    torch.manual_seed(0)
    sac = SAC(5, 2, hidden=32)
    x = torch.randn(7, 5)
    state = torch.random.get_rng_state()
    with torch.no_grad():
        sampled = sac.actor.sample(x)[0]
        torch.random.set_rng_state(state)
        assert torch.equal(sac.act(x), sampled)
    batch = torch.randn(64, 5), torch.rand(64, 2) * 2 - 1, torch.randn(64), torch.randn(64, 5)
    sac.update(*batch)
    assert all(p.requires_grad for p in sac.critic.parameters())
    twin = copy.deepcopy(sac)
    state = torch.random.get_rng_state()
    sac.update(*batch)
    torch.random.set_rng_state(state)
    for p in twin.critic.parameters():  # gradients of a step set to none, as zero_grad would
        p.grad = None
    twin.update(*batch)
    for mine, other in zip(sac.critic.parameters(), twin.critic.parameters(), strict=True):
        assert torch.equal(mine, other)


def test_temperature_steps_as_adam_on_the_temperature_loss_alone():
    """Each update moves log alpha by exactly one Adam step on -log_alpha * (log_pi + target),
    with log_pi of the policy's own draw in that update (the one the actor loss used)."""
    torch.manual_seed(0)
    sac = SAC(5, 2, hidden=32, target_entropy=-1.0)
    x, a, r, x2 = torch.randn(64, 5), torch.rand(64, 2) * 2 - 1, torch.randn(64), torch.randn(64, 5)
    ref = sac.log_alpha.detach().clone().requires_grad_(True)
    ref_opt = torch.optim.Adam([ref], lr=3e-4)
    for step in range(3):
        actor = copy.deepcopy(sac.actor)
        torch.manual_seed(step)
        sac.update(x, a, r, x2)
        torch.manual_seed(step)  # the update's two draws: next actions, then the policy's
        actor.sample(x2)
        logp = actor.sample(x)[1].detach()
        ref_opt.zero_grad()
        (-(ref * (logp + sac.target_entropy)).mean()).backward()
        ref_opt.step()
        assert sac.log_alpha.item() == ref.item()
    assert sac.log_alpha.item() != 0.0


def test_bfloat16_precision_runs_the_products_in_bfloat16():
    sac = SAC(5, 2, hidden=64, precision="bfloat16")
    seen = []
    hook = sac.actor.trunk[0].register_forward_hook(lambda m, i, o: seen.append(o.dtype))
    sac.update(torch.randn(8, 5), torch.zeros(8, 2), torch.zeros(8), torch.randn(8, 5))
    hook.remove()
    assert seen and all(d == torch.bfloat16 for d in seen)
    with pytest.raises(ConfigError, match=r"unknown sac.precision 'fp8'; allowed: float32, bf"):
        method_config("sili", precision="fp8")


def test_target_entropy_sets_where_the_temperature_moves():
    """The temperature rises while the policy's entropy is below the target, falls above it."""
    x, a, r = torch.randn(64, 5), torch.zeros(64, 2), torch.zeros(64)
    moved = {}
    for target in (-20.0, 20.0):
        torch.manual_seed(0)
        sac = SAC(5, 2, hidden=64, target_entropy=target)
        sac.update(x, a, r, x)
        moved[target] = float(sac.log_alpha.detach())
    assert moved[-20.0] < 0.0 < moved[20.0]
    assert SAC(5, 2).target_entropy == -2.0
    agent = SILIAgent(method_config("sac", target_entropy=-4), 3, 2, horizon=10, strategy_dim=2)
    assert agent.sac.target_entropy == -4.0
    agent = SILIAgent(method_config("sac"), 3, 2, horizon=10, strategy_dim=2)
    assert agent.sac.target_entropy == -2.0  # -|A| by default
    agent = SILIAgent(method_config("sac", target_entropy=-4), 3, 2, horizon=10, strategy_dim=2)
    assert agent.sac.target_entropy == -4.0


def test_target_entropy_schedule_is_applied_at_each_update():
    """The temperature chases the scheduled target of the interaction being trained."""
    schedule = Schedule([(4, -2.0), (6, -6.0)])
    agent = _agent(target_entropy_schedule=schedule, random_interactions=0)
    assert agent.sac.target_entropy == -2.0
    _fill(agent, 8)
    seen = {}
    for j in (3, 5, 7):
        agent.update(j)
        seen[j] = agent.sac.target_entropy
    assert seen == pytest.approx({3: -2.0, 5: -4.0, 7: -6.0})
    saved = AgentConfig.from_dict(agent.cfg.to_dict())
    assert saved.sac.target_entropy == schedule
    assert saved.sac.target_entropy.value(5) == pytest.approx(-4.0)
    with pytest.raises(ConfigError, match=r"schedule of sac.target_entropy: value must be a "):
        method_config("sili", target_entropy_schedule=Schedule([(0, float("nan"))]))
    text = method_config("sili", target_entropy_schedule="1500:-2,1600:-4")  # --set's form
    assert text.sac.target_entropy == Schedule(((1500, -2.0), (1600, -4.0)))


def test_discount_schedule_sets_the_critic_targets_gamma_at_each_update():
    """SAC bootstraps with the scheduled gamma of the interaction being trained."""
    schedule = Schedule([(4, 0.9), (6, 0.99)])
    agent = _agent(gamma_schedule=schedule, random_interactions=0)
    assert agent.sac.gamma == 0.9
    _fill(agent, 8)
    seen = {}
    for j in (3, 5, 7):
        agent.update(j)
        seen[j] = agent.sac.gamma
    assert seen == pytest.approx({3: 0.9, 5: 0.945, 7: 0.99})
    # the critic's target uses it: with gamma 0 it is the reward alone
    sac = agent.sac
    x, a, r = torch.randn(16, agent.in_dim), torch.rand(16, 2) * 2 - 1, torch.randn(16)
    a2, logp2 = sac.actor.sample(x)
    sac.gamma = 0.0
    with torch.no_grad():
        q = sac.critic(x, a)
        expected = torch.nn.functional.mse_loss(q, r.expand_as(q)) * 2
        assert float(sac.critic_loss(x, a, r, x, a2, logp2)) == pytest.approx(float(expected))
    saved = AgentConfig.from_dict(agent.cfg.to_dict())
    assert saved.sac.gamma == schedule and saved.sac.gamma.value(5) == pytest.approx(0.945)
    assert method_config("sili").sac.gamma == 0.99
    with pytest.raises(ConfigError, match=r"schedule of sac.gamma: value must be in \[1e-09, 1\]"):
        method_config("sili", gamma_schedule=Schedule([(0, 0.99), (9, 1.5)]))


def test_the_critic_target_is_the_soft_backup_of_the_smaller_target_twin():
    """y = r + gamma (min_k Q'_k(x2, a2) - alpha log pi(a2 | x2)), each critic regressed on it
    (CleanRL's SAC), with target critics that differ from the critics and from each other."""
    torch.manual_seed(0)
    sac = SAC(in_dim=3, act_dim=2, hidden=16, gamma=0.5)
    with torch.no_grad():
        sac.log_alpha.fill_(np.log(0.3))
        for p in sac.critic_target.parameters():
            p.add_(torch.randn_like(p))
    x, a, r, x2, a2 = (
        torch.randn(32, 3),
        torch.rand(32, 2),
        torch.randn(32),
        torch.randn(32, 3),
        torch.rand(32, 2),
    )
    logp2 = torch.randn(32)
    with torch.no_grad():
        twins = sac.critic_target(x2, a2)
        assert (twins[0] < twins[1]).any() and (twins[1] < twins[0]).any()
        y = r + 0.5 * (torch.minimum(twins[0], twins[1]) - 0.3 * logp2)
        q = sac.critic(x, a)
        expected = ((q[0] - y) ** 2).mean() + ((q[1] - y) ** 2).mean()
        assert float(sac.critic_loss(x, a, r, x2, a2, logp2)) == pytest.approx(float(expected))


def test_the_actor_loss_is_alpha_logp_less_the_smaller_critic_twin():
    """alpha log pi(a|x) - min_k Q_k(x, a) at a ~ pi(.|x), alpha held fixed (CleanRL's SAC):
    the policy climbs the pessimistic twin, and its sign makes it climb, not descend."""
    torch.manual_seed(0)
    sac = SAC(in_dim=3, act_dim=2, hidden=16)
    with torch.no_grad():
        sac.log_alpha.fill_(np.log(0.3))
        for p in sac.critic.parameters():
            p.add_(torch.randn_like(p))
    x = torch.randn(64, 3)
    torch.manual_seed(1)
    actor_loss, _ = sac.actor_objective(x)
    torch.manual_seed(1)  # the same draw of a ~ pi(.|x)
    with torch.no_grad():
        a_pi, logp = sac.actor.sample(x)
        twins = sac.critic(x, a_pi)
        assert (twins[0] < twins[1]).any() and (twins[1] < twins[0]).any()
        expected = (0.3 * logp - torch.minimum(twins[0], twins[1])).mean()
    assert actor_loss.item() == pytest.approx(float(expected), rel=1e-5)


def test_the_target_critics_follow_the_critics_by_polyak_averaging():
    torch.manual_seed(0)
    sac = SAC(in_dim=3, act_dim=2, hidden=16, tau=0.1)
    with torch.no_grad():
        for p in sac.critic_target.parameters():
            p.add_(torch.randn_like(p))
    old = [p.clone() for p in sac.critic_target.parameters()]
    sac.update(torch.randn(32, 3), torch.rand(32, 2), torch.randn(32), torch.randn(32, 3))
    for before, critic, target in zip(
        old, sac.critic.parameters(), sac.critic_target.parameters(), strict=True
    ):
        torch.testing.assert_close(target, 0.9 * before + 0.1 * critic.detach())


def test_the_decoder_predicts_each_steps_change_of_state_and_its_reward():
    obs, next_obs = torch.tensor([[1.0, 2.0]]), torch.tensor([[1.5, 1.0]])
    torch.testing.assert_close(
        decoder_targets(obs, next_obs, torch.tensor([-3.0])), torch.tensor([[0.5, -1.0, -3.0]])
    )


def test_transitions_stack_each_steps_state_action_reward_and_next_state():
    obs = torch.arange(6.0).reshape(1, 3, 2)  # s_0 = (0, 1), s_1 = (2, 3), s_2 = (4, 5)
    act, rew = torch.tensor([[[10.0], [11.0]]]), torch.tensor([[20.0, 21.0]])
    expected = torch.tensor([[[0, 1, 10, 20, 2, 3], [2, 3, 11, 21, 4, 5]]], dtype=torch.float32)
    torch.testing.assert_close(transitions(obs, act, rew), expected)


def test_the_policy_acts_on_the_state_this_interactions_latent_and_the_one_before():
    """[s, z^j, z^{j-1}] for SILI, [s, z^j] for LILI; z^{j-1} is zeros in a game's first
    interaction (no history), also in a game started later."""
    sili, lili = _agent("sili"), _agent("lili")
    for agent in (sili, lili):
        _fill(agent, 3)
        agent.Z = np.arange(4 * 4, dtype=np.float32).reshape(4, 4)  # z^0 .. z^3
    s = np.array([7.0, 8.0, 9.0], np.float32)
    np.testing.assert_array_equal(sili.policy_input(s), np.concatenate([s, sili.Z[3], sili.Z[2]]))
    np.testing.assert_array_equal(lili.policy_input(s), np.concatenate([s, lili.Z[3]]))
    sili.begin_game({"strategy": np.zeros(2, np.float32)})
    np.testing.assert_array_equal(sili.policy_input(s), np.concatenate([s, np.zeros(8)]))


def test_lr_schedule_sets_every_sac_optimizers_step_size_at_each_update():
    """A late smaller step: actor, critics and temperature all take the scheduled rate."""
    schedule = Schedule([(4, 3e-4), (6, 3e-5)])
    agent = _agent(lr_schedule=schedule, random_interactions=0)
    sac = agent.sac
    optimizers = (sac.actor_opt, sac.critic_opt, sac.alpha_opt)
    assert {g["lr"] for o in optimizers for g in o.param_groups} == {3e-4}
    _fill(agent, 8)
    seen, moved = {}, {}
    for j in (3, 5, 7):
        before = [p.detach().clone() for p in sac.actor.parameters()]
        agent.update(j)
        (seen[j],) = {g["lr"] for o in optimizers for g in o.param_groups}
        after = sac.actor.parameters()
        moved[j] = max(
            float((p.detach() - q).abs().max()) for p, q in zip(after, before, strict=True)
        )
    # Adam's steps scale with the rate: a tenth of it moves the weights far less
    assert moved[7] < moved[3] / 3, moved
    assert seen == pytest.approx({3: 3e-4, 5: 1.65e-4, 7: 3e-5})
    saved = AgentConfig.from_dict(agent.cfg.to_dict())
    assert saved.sac.lr == schedule and saved.sac.lr.value(5) == pytest.approx(1.65e-4)
    assert method_config("sili").sac.lr == 3e-4
    with pytest.raises(ConfigError, match=r"value must be in \[0, 1\], got -0.1"):
        method_config("sili", lr_schedule=Schedule([(0, 3e-4), (9, -0.1)]))


def test_mistyped_settings_fail_by_name():
    """A --set value of the wrong type is refused up front, naming the setting and the value."""
    with pytest.raises(
        ConfigError, match=r"setting sac.lr must be a number or a schedule .*, got 'abc'"
    ):
        method_config("sili", lr="abc")
    with pytest.raises(ConfigError, match=r"target_entropy must be .*, got 'x'"):
        method_config("sili", target_entropy="x")
    with pytest.raises(ConfigError, match=r"hidden must be a whole number, got 1\.5"):
        method_config("sili", hidden=1.5)
    with pytest.raises(ConfigError, match=r"unknown sac.precision 16; allowed: float32, bf"):
        method_config("sili", precision=16)
    with pytest.raises(ConfigError, match=r"setting sili.beta: '300:0.5x' is not INTERACTION:V"):
        method_config("sili", beta_schedule="0:0,300:0.5x")
    with pytest.raises(ConfigError, match=r"unknown setting 'sac.lrr'; allowed: .*sac.lr"):
        method_config("sili", sac__lrr=1.0)
    cfg = method_config("sili", lr=1, hidden=64.0, stability_scale=None, target_entropy=-3)
    with pytest.raises(ConfigError, match=r"'addons.filter.epss'; allowed: .*sac.lr.*addons."):
        make_run_config("circle-3", "sili", 0, 5, settings={"addons.filter.epss": 0.1})
    for name in ("sac.lrr", "lrr"):  # whichever layer refuses it, the whole list with flat names
        with pytest.raises(ConfigError, match=r"addons.filter.eps, .* flat names .*latent_filter"):
            make_run_config("circle-3", "sili", 0, 5, settings={name: 0.1})
    with pytest.raises(ConfigError) as listed:  # neither is a setting: each is chosen itself
        make_run_config("circle-3", "sili", 0, 5, settings={"foo": 1})
    allowed = str(listed.value).split("allowed: ")[1].split(" (or")[0].split(", ")
    assert "sac.lr" in allowed and "method" not in allowed and "profile" not in allowed
    assert (cfg.sac.lr, cfg.hidden, cfg.sili.scale, cfg.sac.target_entropy) == (1.0, 64, None, -3)
    assert isinstance(cfg.hidden, int) and isinstance(cfg.sac.lr, float)


def test_latent_model_learns_two_strategies():
    """A random walk with reward -|x - g_z|; the strategy flips when the walk ends left of 0.
    The encoder must recover z^j from tau^{j-1} (z^{j-1} from the rewards, the flip from the
    last state) with no label, only by making the decoder's predictions good."""
    torch.manual_seed(0)
    rng = np.random.default_rng(0)
    goals = np.array([-1.0, 1.0])
    n, h = 400, 10
    act = rng.uniform(-1, 1, (n, h, 1)).astype(np.float32)
    pos = np.concatenate([np.zeros((n, 1, 1)), np.cumsum(0.3 * act, 1)], 1)
    time_frac = np.broadcast_to((np.arange(h + 1) / h)[None, :, None], (n, h + 1, 1))
    obs = np.concatenate([pos, time_frac], -1).astype(np.float32)
    z = np.zeros(n, int)
    for j in range(1, n):
        z[j] = 1 - z[j - 1] if obs[j - 1, -1, 0] < 0 else z[j - 1]
    rew = -np.abs(obs[:, 1:, 0] - goals[z][:, None]).astype(np.float32)
    model = LatentModel(2, 1, latent_dim=4, hidden=64, kind="discrete")
    opt = torch.optim.Adam(model.parameters(), lr=1e-3)
    o, a_, r_ = torch.from_numpy(obs), torch.from_numpy(act), torch.from_numpy(rew)
    tr = transitions(o, a_, r_)

    def loss_on(idx):
        return model.loss(tr[idx - 1], o[idx, :-1], a_[idx], o[idx, 1:], r_[idx])

    everything = torch.arange(1, n)
    first = float(loss_on(everything).detach())
    for _ in range(1000):
        loss = loss_on(torch.from_numpy(rng.integers(1, n, 64)))
        opt.zero_grad()
        loss.backward()
        opt.step()
    with torch.no_grad():
        last = float(loss_on(everything))
        cats = model.encode(tr[:-1]).argmax(-1).numpy()
    truth = z[1:]
    # purity: each predicted category stands for one true strategy
    purity = sum(np.bincount(truth[cats == c]).max() for c in np.unique(cats)) / len(truth)
    assert last < 0.2 * first, (first, last)
    assert purity > 0.85, purity


def test_a_checkpoint_saved_before_foreach_resumes_on_it():
    """The latent model's Adam runs on foreach (the same steps, faster); a checkpoint saved
    without it would restore the slower loop."""
    saved = _agent().state_dict()
    for group in saved["model_opt"]["param_groups"]:
        group["foreach"] = None  # as saved before
    agent = _agent()
    agent.load_state_dict(saved)
    assert [g["foreach"] for g in agent.model_opt.param_groups] == [True]


def test_checkpoint_round_trip_restores_everything():
    a1 = _agent()
    _fill(a1, 8)
    a1.update(8)
    blob = io.BytesIO()
    torch.save(a1.state_dict(), blob)  # through bytes, as a checkpoint file is
    blob.seek(0)
    a2 = _agent()
    a2.load_state_dict(torch.load(blob, weights_only=False))
    obs = np.ones(3, np.float32)
    torch.manual_seed(3)
    act1 = a1.act(obs)
    torch.manual_seed(3)
    np.testing.assert_allclose(act1, a2.act(obs))
    np.testing.assert_array_equal(a1.Z, a2.Z)
    assert a1.buffer.n == a2.buffer.n == 8
    for key in KEYS:  # the strategy ids too: only the metrics' breakdowns read them
        np.testing.assert_array_equal(getattr(a1.buffer, key)[:8], getattr(a2.buffer, key)[:8])
    # identical next updates: the RNGs were restored too
    torch.manual_seed(4)
    l1 = a1.update(9)
    torch.manual_seed(4)
    assert a2.update(9) == pytest.approx(l1)


def test_methods_condition_on_the_right_inputs():
    assert _agent("sili").in_dim == 3 + 2 * 4
    assert _agent("lili").in_dim == 3 + 4
    assert _agent("sac").in_dim == 3
    assert _agent("stable").cfg.sili.beta == 1.0
    assert _agent("lili").cfg.sili.beta == 0.0


def test_bad_config_is_named():
    with pytest.raises(ConfigError, match=r"sili.beta must be in \[0, 1\], got 1.5"):
        method_config("sili", beta=1.5)
    with pytest.raises(ConfigError, match="unknown method 'ppo'"):
        method_config("ppo")
    with pytest.raises(ConfigError, match="unknown latent 'fuzzy'"):
        method_config("sili", "fuzzy")


def test_relabel_keeps_the_function_and_refresh_keeps_category_names():
    torch.manual_seed(0)
    model = LatentModel(3, 2, latent_dim=4, hidden=16, kind="discrete")
    traj = torch.randn(20, H, 3 + 2 + 1 + 3)
    obs, act = torch.randn(20, H, 3), torch.randn(20, H, 2)
    z_before = model.encode(traj)
    perm = torch.tensor([2, 0, 3, 1])
    pred_before = model.decode(obs, act, z_before)
    model.relabel(perm)
    z_after = model.encode(traj)
    np.testing.assert_array_equal(z_after.numpy(), z_before[:, perm].numpy())
    torch.testing.assert_close(model.decode(obs, act, z_after), pred_before)

    agent = _agent()
    _fill(agent, 12)
    agent.refresh_latents()
    cached, relabels = agent.Z.argmax(-1).copy(), agent.latents.relabels
    agent.model.relabel(torch.tensor([1, 2, 3, 0]))  # as if training had shuffled the names
    agent.refresh_latents()
    np.testing.assert_array_equal(agent.Z.argmax(-1)[1:], cached[1:])
    assert agent.latents.relabels == relabels + 1


def test_a_refresh_keeps_the_names_of_several_categories_in_use():
    """Three kinds of interaction in distinct categories; training renames the categories (a
    4-cycle); the refresh names them back, and encoding an interaction again agrees."""
    torch.manual_seed(0)
    agent = _agent(latent_merge_threshold=0.0)
    for j in range(12):
        level = np.float32([-4, 0, 4][j % 3])
        obs = np.full((H + 1, 3), level, np.float32)
        obs[:, 1] = -level
        agent.observe_interaction(obs, np.zeros((H, 2), np.float32), np.full(H, level),
                                  obs[0], float(j % 3), {"strategy": np.zeros(2)})  # fmt: skip
    with torch.no_grad():
        agent.model.head.weight.mul_(20)  # categories far apart
    agent.refresh_latents()
    cached = agent.Z.argmax(-1).copy()
    assert len(set(cached[1:])) >= 2
    agent.model.relabel(torch.tensor([1, 2, 3, 0]))
    agent.refresh_latents()
    np.testing.assert_array_equal(agent.Z.argmax(-1), cached)
    again = agent.latents.encode(np.arange(12)).argmax(-1)
    np.testing.assert_array_equal(again, cached[1:])


def test_relabel_moves_the_optimizers_moments_with_the_categories():
    torch.manual_seed(0)
    model = LatentModel(3, 2, latent_dim=4, hidden=16, kind="discrete")
    opt = torch.optim.Adam(model.parameters(), lr=1e-3)
    traj, obs, act = torch.randn(8, H, 9), torch.randn(8, H, 3), torch.randn(8, H, 2)
    for _ in range(3):
        opt.zero_grad()
        model.loss(traj, obs[:, :-1], act[:, :-1], obs[:, 1:], act[:, :-1, 0]).backward()
        opt.step()
    moments = {p: {k: v.clone() for k, v in opt.state[p].items()} for p in model.parameters()}
    perm = torch.tensor([2, 0, 3, 1])
    model.relabel(perm, opt)
    head, last = model.head, model.decoder[-1]
    for name in ("exp_avg", "exp_avg_sq"):
        assert torch.equal(opt.state[head.weight][name], moments[head.weight][name][perm])
        assert torch.equal(opt.state[head.bias][name], moments[head.bias][name][perm])
        before = moments[last.weight][name].unflatten(0, (4, model.out_dim))
        assert torch.equal(opt.state[last.weight][name], before[perm].flatten(0, 1))
        trunk = model.phi[0].weight  # not per category: left alone
        assert torch.equal(opt.state[trunk][name], moments[trunk][name])
    assert opt.state[head.weight]["step"] == moments[head.weight]["step"]
    agent = _agent()
    assert agent.latents.optimizer is agent.model_opt  # refreshes rename through it


def test_head_distances_of_many_categories_fit_in_a_bounded_memory():
    """The heads' pairwise differences grow with ``model.dim`` squared: at 600 categories on 64
    stored interactions they are 3.7 GB at once, which a ``model.dim`` of a few hundred ran out
    of at its first merge; in blocks they fit under a 2 GiB address-space margin."""
    script = """
import resource, torch
from sili_robots.agent.latent import LatentModel
torch.manual_seed(0)
model = LatentModel(3, 1, latent_dim=600, hidden=16, kind="discrete")
obs, act = torch.randn(64, 10, 3), torch.randn(64, 10, 1)
size = int(open("/proc/self/statm").read().split()[0]) * resource.getpagesize()
resource.setrlimit(resource.RLIMIT_AS, (size + 2**31, resource.RLIM_INFINITY))
d = model.head_distances(obs, act, torch.ones(4))
print(tuple(d.shape), bool(torch.isfinite(d).all()))
"""
    res = subprocess.run(
        [sys.executable, "-c", script], capture_output=True, text=True, timeout=300
    )
    assert res.stdout.split("\n")[0] == "(600, 600) True", res.stderr[-800:]


def test_the_target_scale_of_a_single_transition_is_one_without_a_warning():
    """A latent batch of one interaction of one step has no spread: torch's std warns
    ('degrees of freedom is <= 0') and gives NaN, which the scale replaced by 1 only after."""
    import warnings

    from sili_robots.agent.latent import target_scale

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert torch.equal(target_scale(torch.randn(1, 1, 4)), torch.ones(4))
    assert torch.equal(
        target_scale(torch.tensor([[[1.0, 2.0]], [[1.0, 4.0]]]))[0], torch.tensor(1.0)
    )


def test_a_stability_scale_of_zero_is_kept_and_none_means_the_horizon():
    assert _agent(stability_scale=0.0).stability_scale == 0.0
    assert _agent().stability_scale == H


def test_categories_with_the_same_behaviour_count_as_one_strategy():
    torch.manual_seed(0)
    model = LatentModel(3, 2, latent_dim=3, hidden=16, kind="discrete")
    last = model.decoder[-1]
    with torch.no_grad():  # heads [k, out]: category 1 copies 0, category 2 predicts reward + 5
        w, b = last.weight.view(3, 4, -1), last.bias.view(3, 4)
        w[1], b[1] = w[0], b[0]
        w[2], b[2] = w[0], b[0]
        b[2, -1] += 5.0
    obs, act = torch.randn(10, H, 3), torch.randn(10, H, 2)
    d = model.head_distances(obs, act, torch.ones(4))
    assert float(d[0, 1]) == pytest.approx(0.0, abs=1e-6)
    assert float(d[0, 2]) == pytest.approx(5.0, rel=1e-4)
    assert category_groups(d, [1, 0, 2], threshold=0.5) == {1: 1, 0: 1, 2: 2}
    assert category_groups(d, [1, 0, 2], threshold=6.0) == {1: 1, 0: 1, 2: 1}

    whole = model.head_distances(obs, act, torch.ones(4))
    latent_module = sys.modules[LatentModel.__module__]
    for elements in (1, 10 * H * 3 * 4 * 2):  # a row at a time; two rows at a time
        with pytest.MonkeyPatch.context() as mp:
            mp.setattr(latent_module, "DISTANCE_ELEMENTS", elements)
            assert torch.equal(model.head_distances(obs, act, torch.ones(4)), whole)

    # in the agent: when every head predicts the same, every latent is one category and the
    # stability reward never pays for a change; with grouping off the raw categories change
    for threshold, one_category in ((0.5, True), (0.0, False)):
        agent = _agent(latent_merge_threshold=threshold)
        with torch.no_grad():
            w = agent.model.decoder[-1].weight.view(4, 4, -1)
            bias = agent.model.decoder[-1].bias.view(4, 4)
            w[1:], bias[1:] = w[0], bias[0]
            agent.model.head.bias.copy_(torch.tensor([0.0, 0.0, 0.0, -50.0]))
            agent.model.head.weight.mul_(100.0)  # several categories in use
        _fill(agent, 30)
        agent.refresh_latents()
        assert (len(np.unique(agent.Z[1:].argmax(-1))) == 1) is one_category


@pytest.mark.parametrize("estimator", ["expected", "marginal", "gumbel"])
def test_every_discrete_estimator_trains_encoder_and_decoder(estimator):
    torch.manual_seed(0)
    model = LatentModel(3, 2, latent_dim=4, hidden=16, kind="discrete", estimator=estimator)
    prev, obs = torch.randn(8, H, 3 + 2 + 1 + 3), torch.randn(8, H + 1, 3)
    loss = model.loss(prev, obs[:, :-1], torch.randn(8, H, 2), obs[:, 1:], torch.randn(8, H))
    loss.backward()
    assert torch.isfinite(loss)
    assert model.head.weight.grad.abs().sum() > 0  # the encoder learns
    assert model.decoder[-1].weight.grad.abs().sum() > 0  # the decoder learns


@pytest.mark.parametrize("kind", ["discrete", "continuous"])
def test_decoder_backward_copies_no_slices(kind):
    """The decoder runs on the 2-D view of its rows: in-place ReLUs on a 3-D layer output make
    autograd copy slices into a zero-filled buffer in every backward pass; the value is the
    same as the MLP applied to the 3-D rows directly."""
    torch.manual_seed(0)
    model = LatentModel(3, 2, latent_dim=4, hidden=16, kind=kind)
    traj, obs, act = (
        torch.randn(6, H, 3 + 2 + 1 + 3),
        torch.randn(6, H + 1, 3),
        torch.randn(6, H, 2),
    )
    loss = model.loss(traj, obs[:, :-1], act, obs[:, 1:], torch.randn(6, H))
    seen, stack = set(), [loss.grad_fn]
    while stack:
        fn = stack.pop()
        if fn is not None and fn not in seen:
            seen.add(fn)
            stack.extend(nxt for nxt, _ in fn.next_functions)
    names = {type(fn).__name__ for fn in seen}
    assert "ReluBackward0" in names and not names & {"CopySlices", "AsStridedBackward0"}
    z = model.encode(traj)
    x = torch.cat(
        [obs[:, :-1], act] + ([] if kind == "discrete" else [z[:, None].expand(6, H, 4)]), -1
    )
    direct = model.decoder(x.clone())
    if kind == "discrete":
        direct = (z[:, None, :, None] * direct.unflatten(-1, (4, 4))).sum(-2)
    torch.testing.assert_close(model.decode(obs[:, :-1], act, z), direct, rtol=0, atol=0)


def test_preact_penalty_pulls_a_saturated_continuous_encoder_back():
    """Saturated tanh passes no gradient, so only the penalty brings the output back."""
    prev, obs = torch.randn(8, H, 3 + 2 + 1 + 3), torch.randn(8, H + 1, 3)
    act, rew = torch.randn(8, H, 2), torch.randn(8, H)

    def trained_output(penalty):
        torch.manual_seed(0)
        model = LatentModel(
            3, 2, latent_dim=4, hidden=16, kind="continuous", preact_penalty=penalty
        )
        with torch.no_grad():
            model.head.bias.fill_(20.0)  # every output deep in tanh's flat tail
        opt = torch.optim.Adam(model.parameters(), lr=1e-2)
        for _ in range(20):
            opt.zero_grad()
            model.loss(prev, obs[:, :-1], act, obs[:, 1:], rew).backward()
            opt.step()
        return model.encode_logits(prev).abs().mean().item()

    assert trained_output(1e-3) < trained_output(0.0) - 0.1
    assert method_config("sili", "continuous").model.preact_penalty == 1e-3  # the default
    saved = {"method": "sili", "latent": "continuous", "latent_dim": 10}  # the flat layout
    run = migrate_run({"agent": saved})  # of a run saved before the setting existed
    assert AgentConfig.from_dict(run["agent"]).model.preact_penalty == 0.0
    with pytest.raises(ConfigError, match=r"model.preact_penalty must be >= 0, got -1"):
        method_config("sili", latent_preact_penalty=-1.0)


def test_unknown_estimator_is_named():
    with pytest.raises(ConfigError, match=r"unknown model.estimator 'vq'"):
        method_config("sili", latent_estimator="vq")


def test_posterior_stability_pays_only_for_a_strategy_shown_to_stay():
    """stability_distance="posterior": d = 1 - P(strategy during j = predicted z^{j+1})."""
    agent = _agent(stability_distance="posterior")
    post = _posteriors(agent)
    assert post.replaces_distance
    with torch.no_grad():  # constant heads: category k predicts s' - s = 0 and reward 5k
        last = agent.model.decoder[-1]
        last.weight.zero_()
        last.bias.zero_()
        last.bias.view(4, 4)[:, -1] = torch.tensor([0.0, 5.0, 10.0, 15.0])
    obs = np.ones((H + 1, 3), np.float32)  # standing still: s' - s = 0 on every step
    act = np.zeros((H, 2), np.float32)
    info = {"strategy": np.zeros(2, np.float32)}
    for reward in (0.0, 5.0, 2.5):  # shows category 0; shows 1; halfway, tells 0 and 1 apart not
        agent.observe_interaction(
            obs,
            act,
            np.full(H, reward, np.float32),
            obs[0],
            0.0,
            info,
            refresh=False,
        )
    agent.Z = np.eye(4, dtype=np.float32)[[0, 0, 1, 0]]  # categories in use: 0 and 1
    post.P = post.posteriors(np.arange(3))
    np.testing.assert_allclose(post.P[:, :2], [[1, 0], [0, 1], [0.5, 0.5]], atol=1e-6)
    assert np.all(post.P[:, 2:] == 0)  # categories not in use get no mass
    # z^1 = 0 predicted after interaction 0 (which showed 0): stayed; z^2 = 1 after interaction 1
    # (which showed 1): stayed; z^3 = 0 after an interaction that cannot tell: half a change
    j, t = np.arange(3)[:, None], np.full((3, 1), H - 1)
    r = agent._stability_rewards(j, t, t == H - 1, np.zeros((3, 1, 3)))
    np.testing.assert_allclose(r[:, 0], [0, 0, -0.5 * agent.stability_scale], atol=1e-5)
    agent.Z = np.eye(4, dtype=np.float32)[[0, 1, 0, 0]]  # now both predictions say "changed"
    post.P = post.posteriors(np.arange(3))
    r = agent._stability_rewards(j, t, t == H - 1, np.zeros((3, 1, 3)))
    np.testing.assert_allclose(r[:2, 0], [-agent.stability_scale] * 2, atol=1e-5)
    assert agent._stats(1, obs[0], {}).stability_reward == pytest.approx(-1.0, abs=1e-5)
    # the posteriors survive a checkpoint round trip
    other = _agent(stability_distance="posterior")
    other.load_state_dict(agent.state_dict())
    np.testing.assert_array_equal(_posteriors(other).P, post.P)


def test_hindsight_stability_compares_the_strategies_in_effect_in_both_interactions():
    """stability_distance="hindsight": d = 1 - sum_k P[j, k] P[j+1, k]."""
    agent = _agent(stability_distance="hindsight")
    _fill(agent, 3)
    agent.Z = np.eye(4, dtype=np.float32)[[0, 0, 0, 1]]
    _posteriors(agent).P = np.array([[1, 0, 0, 0], [0, 1, 0, 0], [0.5, 0.5, 0, 0]], np.float32)
    j, t = np.arange(3)[:, None], np.full((3, 1), H - 1)
    r = agent._stability_rewards(j, t, t == H - 1, np.zeros((3, 1, 3)))
    # 0 -> 1: changed for sure; 1 -> half/half: half; the newest (no successor yet) against the
    # predicted z^3 = category 1: half
    np.testing.assert_allclose(r[:, 0], np.array([-1.0, -0.5, -0.5]) * agent.stability_scale)
    agent.Z[2] = np.eye(4, dtype=np.float32)[1]  # the encoder's prediction does not matter here
    r2 = agent._stability_rewards(j, t, t == H - 1, np.zeros((3, 1, 3)))
    np.testing.assert_allclose(r2[:2], r[:2])
    # the newest is judged against the prediction z^3 (category 0), not against itself
    agent.Z[3] = np.eye(4, dtype=np.float32)[0]
    _posteriors(agent).P[2] = [0, 1, 0, 0]
    r3 = agent._stability_rewards(j, t, t == H - 1, np.zeros((3, 1, 3)))
    assert r3[2, 0] == pytest.approx(-agent.stability_scale)


def test_posteriors_spread_over_the_categories_in_use_only():
    """Z[0], the zeros of "no history", names no category in use."""
    agent = _agent(stability_distance="hindsight")
    _fill(agent, 3)
    agent.Z = np.concatenate([np.zeros((1, 4)), np.eye(4)[[1, 2, 1]]]).astype(np.float32)
    post = _posteriors(agent).posteriors(np.arange(3))
    assert (post[:, [0, 3]] == 0).all()
    np.testing.assert_allclose(post.sum(-1), 1.0, rtol=1e-6)


def test_unknown_stability_distance_is_named():
    with pytest.raises(
        ConfigError, match=r"unknown addons.stability_distance 'kl'.*latents, posterior"
    ):
        method_config("sili", stability_distance="kl")


def test_beta_schedule_holds_start_for_the_delay_then_ramps():
    schedule = Schedule.ramp(start=0.0, end=0.5, length=50, delay=250)
    values = [schedule.value(i) for i in (0, 249, 250, 275, 300, 1000)]
    assert values == pytest.approx([0.0, 0.0, 0.0, 0.25, 0.5, 0.5])
    agent = _agent(beta_schedule=schedule)
    seen = {}
    for j in (100, 400):
        agent.update(j, rl=False)
        seen[j] = agent.beta
    assert seen == {100: 0.0, 400: 0.5}
    assert Schedule.ramp(1.0, 0.5, 10).value(5) == pytest.approx(0.75)  # ramps at once
    with pytest.raises(ConfigError, match="interaction must be >= 0"):
        method_config("sili", beta_schedule=Schedule.ramp(0.0, 0.5, 10, delay=-1))


def test_beta_schedule_rises_then_falls_through_its_points():
    schedule = Schedule([(250, 0.0), (300, 0.5), (1500, 0.5), (1600, 0.1)])
    values = [schedule.value(i) for i in (0, 275, 300, 1000, 1550, 1600, 5000)]
    assert values == pytest.approx([0.0, 0.25, 0.5, 0.5, 0.3, 0.1, 0.1])
    with pytest.raises(ConfigError, match="must increase, got 250 after 300"):
        method_config("sili", beta_schedule=Schedule([(300, 0.5), (250, 0.0)]))
    with pytest.raises(ConfigError, match="must increase, got 250 after 250"):  # two values at once
        method_config("sili", beta_schedule=Schedule([(250, 0.0), (250, 0.5)]))
    with pytest.raises(ConfigError, match=r"sili.beta: value must be in \[0, 1\], got 1.5 at"):
        method_config("sili", beta_schedule=Schedule([(9, 1.5)]))


def test_saved_schedules_load_both_forms():
    """Runs saved with the single-ramp form still resume with the same b at every interaction."""
    ramp = {"start": 0.0, "end": 0.5, "length": 50, "delay": 250}
    points = {"points": [[250, 0.0], [300, 0.5], [1500, 0.5], [1600, 0.1]]}
    old = AgentConfig.from_dict(migrate_run({"agent": {"beta_schedule": ramp}})["agent"])
    new = AgentConfig.from_dict(migrate_run({"agent": {"beta_schedule": points}})["agent"])
    assert [old.sili.beta.value(i) for i in (249, 275, 2000)] == pytest.approx([0.0, 0.25, 0.5])
    assert new.sili.beta.value(1550) == pytest.approx(0.3)
    assert AgentConfig.from_dict(new.to_dict()).sili.beta == new.sili.beta


def test_last_step_encoder_reads_the_last_transition_itself():
    """Pooling alone cannot tell the order of a trajectory's transitions; with ``last_step``
    the encoder sees which one came last."""
    torch.manual_seed(0)
    traj = torch.randn(1, 6, 9)
    swapped = traj[:, [0, 1, 2, 3, 5, 4]]  # the same set, another last transition
    pooled = LatentModel(3, 2, 4, 32, "continuous")
    torch.testing.assert_close(pooled.encode_logits(traj), pooled.encode_logits(swapped))
    last = LatentModel(3, 2, 4, 32, "continuous", readouts=[last_transition])
    assert not torch.allclose(last.encode_logits(traj), last.encode_logits(swapped))
    agent = _agent(latent_last_step=True)
    assert agent.model.readouts == [last_transition]
    assert agent.model.head.in_features == 3 * 32
    assert _agent().model.head.in_features == 2 * 32  # off: no add-on, pooled features only
    with pytest.raises(ConfigError, match=r"addons.last_step must be true or false, got 1"):
        method_config("sili", latent_last_step=1)


def test_refreshes_use_few_batch_sizes_and_the_same_latents(monkeypatch):
    """Every distinct batch shape costs memory for the rest of a run (oneDNN kernels,
    allocator fragments), so refreshes pad their chunks to a few sizes."""
    import sili_robots.agent.latent_cache as cache_module

    monkeypatch.setattr(cache_module, "REFRESH_CHUNK", 8)
    agent = _agent(latent="continuous")
    encode, sizes = agent.latents.encode, []
    agent.latents.encode = lambda idx: sizes.append(len(idx)) or encode(idx)
    for n in range(1, 22):
        _fill(agent, 1)
        agent.refresh_latents()
        assert agent.buffer.n == n and len(agent.Z) == n + 1
    assert set(sizes) == {1, 2, 4, 8}
    one_by_one = np.concatenate([encode(np.array([j])) for j in range(21)])
    np.testing.assert_allclose(agent.Z[1:], one_by_one, atol=1e-6)
    np.testing.assert_array_equal(cache_module.pad_rows(np.arange(5)), [0, 1, 2, 3, 4, 4, 4, 4])
    assert [cache_module.padded_size(m) for m in (3, 64, 65, 130, 512)] == [4, 64, 128, 192, 512]
    assert largest_power_of_two(700) == 512


def test_per_step_credit_pays_the_change_into_each_interaction_on_every_step():
    """The paper's credit (its profile): every step of interaction j is paid -d(z^{j-1}, z^j),
    and nothing is paid for the change into z^1 (z^0 is no history)."""
    agent = _agent(sili__credit="per_step")
    _fill(agent, 6)
    agent.Z = np.eye(4, dtype=np.float32)[[0, 1, 1, 2, 2, 3, 3]]  # z^0..z^6
    j = np.repeat(np.arange(6)[:, None], H, 1)
    t = np.tile(np.arange(H), (6, 1))
    r = agent._stability_rewards(j, t, t == H - 1, np.zeros((6, H, 3)))
    # into z^1 free, z^1->z^2 same, z^2->z^3 change, same, z^4->z^5 change
    np.testing.assert_array_equal(r, np.repeat([[0, 0, 0, -1, 0, -1]], H, 0).T)


@pytest.mark.parametrize("sample", [False, True])
def test_the_paper_profiles_sampled_latents_differ_between_encodings_of_one_interaction(sample):
    """``model.sample`` (the paper's Gumbel-max z^j) draws a category per encoding; the package's
    argmax gives one interaction one category."""
    agent = _agent(model__sample=sample)
    _fill(agent, 3)
    categories = agent.latents.encode(np.full(200, 1)).argmax(-1)
    assert (len(np.unique(categories)) > 1) == sample


def test_smirls_reward_is_the_log_likelihood_under_the_states_seen_before():
    """SMiRL pays log N(s_{t+1}; mean, std) of every state visited before the interaction."""
    agent = _agent("smirl", sili__beta=1.0)
    _fill(agent, 4)
    seen = agent.buffer.obs[:3, 1:].reshape(-1, 3).astype(np.float64)
    mean, std = seen.mean(0), np.maximum(seen.std(0), agent.cfg.sili.smirl_std_floor)
    s = agent.buffer.obs[3, 1:].astype(np.float64)
    expected = (
        -0.5 * (((s - mean) / std) ** 2).sum(-1) - np.log(std).sum() - 1.5 * np.log(2 * np.pi)
    )
    np.testing.assert_allclose(agent.buffer.aux[3], expected, rtol=1e-5)
    j, t = np.full((1, H), 3), np.arange(H)[None]
    np.testing.assert_array_equal(
        agent._stability_rewards(j, t, t == H - 1, np.zeros((1, H, 3))), agent.buffer.aux[j, t]
    )
    s0 = agent.buffer.obs[0, 1:].astype(np.float64)  # before any state: a unit Gaussian at 0
    first = -0.5 * (s0**2).sum(-1) - 1.5 * np.log(2 * np.pi)
    np.testing.assert_allclose(agent.buffer.aux[0], first, rtol=1e-5)


def test_smirl_after_a_single_state_scores_under_a_unit_spread():
    """With H = 1 (Driving allows it) the density has seen one state after the first
    interaction: its spread is undefined and stays the unit Gaussian's, not the floor."""
    agent = make_agent("smirl", horizon=1, sili__beta=1.0, hidden=32)
    rng = np.random.default_rng(3)
    for _ in range(2):
        agent.observe_interaction(
            rng.normal(size=(2, 3)).astype(np.float32),
            rng.uniform(-1, 1, (1, 2)).astype(np.float32),
            rng.normal(size=1).astype(np.float32),
            rng.normal(size=3).astype(np.float32),
            0.0,
            {"strategy": np.array([1.0, 0.0], np.float32)},
        )
    z = agent.buffer.obs[1, 1].astype(np.float64) - agent.buffer.obs[0, 1]  # mean: s of j = 0
    np.testing.assert_allclose(
        agent.buffer.aux[1, 0], -0.5 * (z**2).sum() - 1.5 * np.log(2 * np.pi), rtol=1e-5
    )


@pytest.mark.parametrize("method", ["sili", "sac"])
def test_latent_model_schedules_move_the_model_and_are_ignored_without_one(method):
    """The model's rate, usage bonus and penalty follow their schedules; a method without a
    latent model ignores them, as it ignores their constant values."""
    agent = _agent(
        method,
        random_interactions=0,
        model__lr=Schedule([(4, 1e-3), (6, 1e-4)]),
        model__usage_bonus=Schedule([(4, 0.1), (6, 0.0)]),
        model__preact_penalty=Schedule([(4, 0.0), (6, 0.01)]),
    )
    _fill(agent, 8)
    for j in (3, 5, 7):
        losses = agent.update(j)
    assert "critic_loss" in losses
    if method == "sili":
        assert [g["lr"] for g in agent.model_opt.param_groups] == [pytest.approx(1e-4)]
        assert (agent.model.usage_bonus, agent.model.preact_penalty) == (0.0, 0.01)


@pytest.mark.parametrize(
    ("method", "latent", "addon", "needs"),
    [("sac", None, HindsightPosteriors(), "learned latents"),
     ("sili", "continuous", HindsightPosteriors(), "discrete latents"),
     ("oracle", None, LatentFilter(0.1), "learned latents")],
)  # fmt: skip
def test_an_addon_wired_in_directly_is_refused_without_the_latents_it_reads(
    method, latent, addon, needs
):
    """The settings refuse these before a run; given to the agent itself they failed later,
    with an AttributeError deep in the add-on."""
    cfg = method_config(method, latent, hidden=32)
    with pytest.raises(ConfigError, match=f"add-on {addon.name} needs {needs}"):
        SILIAgent(cfg, 3, 2, H, 2, addons=[addon])
    agent = SILIAgent(cfg, 3, 2, H, 2)
    with pytest.raises(ConfigError, match=f"add-on {addon.name} needs {needs}"):
        agent.attach_addon(addon)
    assert agent.addons == []  # left as it was


@pytest.mark.parametrize("setting", [{"addons__stability_distance": "hindsight"},
                                     {"addons__change_fraction": 0.2}])  # fmt: skip
def test_posteriors_need_discrete_latents_and_runs_saved_with_them_record_them_off(setting):
    """Continuous latents have no categories to take posteriors of: refused, where earlier
    versions left the add-on out; a run saved then resumes as it trained."""
    with pytest.raises(ConfigError, match=r"posteriors .* needs discrete latents, got latent 'co"):
        run_config("sili", "continuous", **setting)
    assert run_config("sili", "discrete", **setting).addons.active() == ["posteriors"]
    saved = run_config("sili", "continuous").to_dict()
    saved["addons"].update({k.removeprefix("addons__"): v for k, v in setting.items()})
    migrated = migrate_run(saved)
    assert migrated["addons"] == run_config("sili", "continuous").to_dict()["addons"]
    assert migrate_run(run_config("sili", "discrete", **setting).to_dict())["addons"] == {
        **saved["addons"],
        **{k.removeprefix("addons__"): v for k, v in setting.items()},
    }


def test_the_settings_allow_exactly_the_kernels_and_estimators_the_code_runs():
    """The settings' allowed values (``agent/config.py``) and the code's own lists are kept in
    two places: adding a kernel, precision or estimator to one must add it to the other."""
    import typing

    from sili_robots.agent.config import Estimator, Matmul, Precision
    from sili_robots.agent.latent import ESTIMATORS
    from sili_robots.agent.matmul import MATMULS, PRECISIONS

    assert set(typing.get_args(Matmul)) == set(MATMULS)
    assert set(typing.get_args(Precision)) == set(PRECISIONS)
    assert set(typing.get_args(Estimator)) == set(ESTIMATORS)


def test_the_replay_keeps_every_interaction_as_it_grows():
    """Its arrays double when full (first at 256 interactions): nothing stored may be lost."""
    from sili_robots.agent.buffer import InteractionBuffer

    buf = InteractionBuffer(obs_dim=3, act_dim=2, horizon=H, capacity=2)
    for j in range(5):
        f = np.float32(j)
        buf.add(np.full((H + 1, 3), f), np.full((H, 2), f), np.full(H, f), np.full(H, -f),
                np.full(3, f), float(j))  # fmt: skip
    assert buf.n == 5 and buf.capacity >= 5
    for j in range(5):
        stored = [buf.obs[j], buf.act[j], buf.rew[j], -buf.aux[j], buf.next_first[j]]
        assert all((a == j).all() for a in stored) and buf.strategy_id[j] == j


def test_smirls_reward_is_bounded_far_from_the_states_seen():
    """A state far outside a tight density would give a log-likelihood in the millions: the
    reward is clipped to +-300 so it cannot swamp the task reward."""
    from sili_robots.agent.smirl import RunningGaussian

    density = RunningGaussian(2)
    density.update(np.zeros((10, 2)))
    assert density.log_likelihood(np.array([[100.0, 100.0]]))[0] == -300.0
    assert -300.0 < density.log_likelihood(np.array([[0.01, 0.0]]))[0] < 300.0


def test_behaviour_groups_are_led_by_their_most_used_category():
    """A chain 0 ~ 1 ~ 2 with 0 and 2 apart: the most used (0) leads and takes 1; 2 stays."""
    from sili_robots.agent.buffer import InteractionBuffer
    from sili_robots.agent.latent_cache import LatentCache

    class Heads:
        def head_distances(self, obs, act, scale):
            return torch.tensor([[0.0, 0.1, 1.0], [0.1, 0.0, 0.1], [1.0, 0.1, 0.0]])

    buffer = InteractionBuffer(2, 1, 3, capacity=8)
    buffer.obs[:6] = np.random.default_rng(0).normal(size=(6, 4, 2))
    buffer.n = 6
    cache = LatentCache(
        Heads(), buffer, "discrete", 3, np.random.default_rng(0), merge_threshold=0.5
    )
    assert list(cache._behaviour_groups(np.array([0, 0, 0, 1, 1, 2]))) == [0, 0, 2]


def test_the_critic_sees_the_previous_interactions_latent_within_and_across_interactions():
    agent = _agent()
    _fill(agent, 6)
    agent.Z = np.eye(4, dtype=np.float32)[[0, 1, 2, 3, 0, 1, 2]] * np.arange(1, 8)[:, None]
    x, _, _, x2 = agent.sample_batches(50, beta=0.5)
    x, x2 = x.reshape(-1, x.shape[-1]).numpy(), x2.reshape(-1, x2.shape[-1]).numpy()
    b = agent.buffer
    seen_first = False
    for row, row2 in zip(x, x2, strict=True):
        j, t = (int(i[0]) for i in np.where((b.obs[:, :-1] == row[:3]).all(-1)))
        prev = agent.Z[j - 1] if j >= 1 else np.zeros(4, np.float32)  # z^{j-1}; none for j = 0
        seen_first |= j == 0
        np.testing.assert_array_equal(row[7:11], prev)
        if t < H - 1:  # the next step of the same interaction: still z^j, z^{j-1}
            np.testing.assert_array_equal(row2[7:11], prev)
    assert seen_first


def test_partial_stability_does_not_count_the_first_observations_flag_again():
    agent = _agent(latent="partial")
    flags = [np.array([1, 0, 0, 1, 0, 0, 0], np.float32)] * 2  # obs_0..obs_H, next_first
    _fill(agent, 2, flags)
    stats = agent._stats(1, np.array([0, 0, 0], np.float32), {})
    assert stats.stability_reward == -1.0  # only the flag at t = 3; obs_0's belongs to j - 1


def test_a_continuous_latent_that_stays_put_is_logged_unchanged():
    agent = _agent(latent="continuous")
    _fill(agent, 3)
    agent.Z = np.array([[0, 0, 0, 0], [1, 0, 0, 0], [1, 0, 0, 0], [1, 2, 0, 0]], np.float32)
    assert [agent._stats(j, np.zeros(3, np.float32), {}).latent_changed for j in range(3)] == [
        False,
        False,
        True,
    ]


def test_an_update_takes_horizon_times_updates_per_step_sac_steps_carrying_fractions():
    agent = _agent(random_interactions=0, updates_per_step=0.3)
    _fill(agent, 3)
    steps = []
    for j in range(3):
        agent.update(j)
        state = agent.sac.critic_opt.state[next(agent.sac.critic.parameters())]
        steps.append(int(state["step"]) if state else 0)
    assert steps == [1, 3, 4]  # credit 1.5, 1.5 + 1.5 = 3.0, 4.5 (H = 5)


def test_an_update_trains_on_the_reward_weighted_by_the_agents_b():
    agent = _agent("stable", latent="partial", random_interactions=0, updates_per_step=0.2)
    _fill(agent, 3, [np.array([0, 1, 0, 0, 1, 0, 1], np.float32)] * 3)
    assert agent.beta == 1.0
    seen = []
    update = agent.sac.update
    agent.sac.update = lambda x, a, r, x2: (
        seen.append((r.clone(), x2.clone())) or update(x, a, r, x2)
    )
    agent.update(3)
    assert len(seen) == 1
    r, x2 = seen[0]
    np.testing.assert_array_equal(r.numpy(), -x2[:, 2].numpy())  # R_stable alone: -flag
    agent = _agent("sili", "partial", random_interactions=0, updates_per_step=0.2, sili__beta=0.3)
    _fill(agent, 3, [np.array([0, 1, 0, 0, 1, 0, 1], np.float32)] * 3)
    seen, update = [], agent.sac.update
    agent.sac.update = lambda x, a, r, x2: seen.append(r.clone()) or update(x, a, r, x2)
    drawn = copy.deepcopy(agent.rng.bit_generator.state)
    agent.update(3)
    agent.rng.bit_generator.state = drawn  # the same batch, weighted with b = 0.3 by hand
    torch.testing.assert_close(seen[0], agent.sample_batches(1, 0.3)[2][0], rtol=0, atol=0)


def test_the_latent_model_learns_each_pair_from_the_previous_interaction_and_the_next():
    agent = _agent()
    _fill(agent, 8)
    b = agent.buffer
    calls = []
    loss = agent.model.loss

    def spy(prev, obs, act, next_obs, rew):
        calls.append((prev.clone(), obs.clone(), act.clone(), next_obs.clone(), rew.clone()))
        return loss(prev, obs, act, next_obs, rew)

    agent.model.loss = spy
    agent.update_latent_model(5)
    assert len(calls) == 5
    for prev, obs, act, next_obs, rew in calls:
        j = np.array([np.where((b.obs[: b.n, 0] == o[0].numpy()).all(-1))[0][0] for o in obs])
        assert (j >= 1).all()  # interaction 0 has no previous one to infer z^0 from
        o, a, r = (torch.from_numpy(x[j]) for x in (b.obs, b.act, b.rew))
        torch.testing.assert_close(obs, o[:, :-1], rtol=0, atol=0)
        torch.testing.assert_close(next_obs, o[:, 1:], rtol=0, atol=0)
        torch.testing.assert_close(act, a, rtol=0, atol=0)
        torch.testing.assert_close(rew, r, rtol=0, atol=0)
        expected = transitions(*(torch.from_numpy(x[j - 1]) for x in (b.obs, b.act, b.rew)))
        torch.testing.assert_close(prev, expected, rtol=0, atol=0)


def test_rl_batches_draw_from_every_stored_interaction_the_newest_too():
    agent = _agent("lili")
    _fill(agent, 3)
    assert set(_sampled_interactions(agent, 20).ravel()) == {0, 1, 2}


def _round_trip(a1, a2):
    blob = io.BytesIO()
    torch.save(a1.state_dict(), blob)
    blob.seek(0)
    a2.load_state_dict(torch.load(blob, weights_only=False))


def test_a_checkpoint_restores_the_update_credit():
    a1 = _agent(random_interactions=0, updates_per_step=0.3)
    _fill(a1, 2)
    a1.update(0)
    assert a1._update_credit == pytest.approx(0.5)
    a2 = _agent(random_interactions=0, updates_per_step=0.3)
    _round_trip(a1, a2)
    assert a2._update_credit == pytest.approx(0.5)


def test_a_checkpoint_restores_torchs_random_state_for_the_next_draws():
    """A resumed run draws the actions the uninterrupted one would (no reseeding between)."""
    a1 = _agent()
    _fill(a1, 3)
    obs = np.ones(3, np.float32)
    torch.manual_seed(11)
    state = a1.state_dict()
    act1 = a1.act(obs)  # the next draw after the save
    a2 = _agent()
    torch.manual_seed(0)  # torch's state moved on in between
    a2.load_state_dict(state)
    np.testing.assert_array_equal(act1, a2.act(obs))


def test_a_checkpoint_restores_smirls_state_density():
    a1 = _agent("smirl", sili__beta=1.0)
    _fill(a1, 3)
    a2 = _agent("smirl", sili__beta=1.0)
    _round_trip(a1, a2)
    assert a2.smirl.count == a1.smirl.count == 3 * H
    np.testing.assert_array_equal(a2.smirl.mean, a1.smirl.mean)
    np.testing.assert_array_equal(a2.smirl.m2, a1.smirl.m2)


def test_a_checkpoint_restores_the_merged_category_mapping():
    a1 = _agent()
    a1.latents.category_map = np.array([0, 0, 2, 2])
    a2 = _agent()
    _round_trip(a1, a2)
    np.testing.assert_array_equal(a2.latents.category_map, [0, 0, 2, 2])


def test_latents_refresh_every_refresh_every_interactions_and_not_when_told_not_to():
    agent = _agent(model__refresh_every=4)
    refreshes = []
    refresh = agent.latents.refresh
    agent.latents.refresh = lambda: refreshes.append(agent.buffer.n) or refresh()
    _fill(agent, 9)
    assert refreshes == [4, 8]
    rng = np.random.default_rng(5)
    for _ in range(4):  # stored interactions 10..13: 12 would refresh, but not when told not to
        agent.observe_interaction(
            rng.normal(size=(H + 1, 3)).astype(np.float32),
            np.zeros((H, 2), np.float32),
            np.zeros(H, np.float32),
            np.zeros(3, np.float32),
            0.0,
            {"strategy": np.zeros(2, np.float32)},
            refresh=False,
        )
    assert refreshes == [4, 8]


@pytest.mark.parametrize(
    ("path", "value", "message"),
    [
        ("sac.tau", 1.5, r"sac.tau must be in \[0, 1\], got 1.5"),
        ("model.dim", 0, r"model.dim must be >= 1, got 0"),
        ("model.batch", 0, r"model.batch must be >= 1, got 0"),
        ("model.refresh_every", 0, r"model.refresh_every must be >= 1, got 0"),
        ("sili.scale", -1.0, r"sili.scale must be >= 0, got -1"),
        ("sili.smirl_std_floor", 0.0, r"sili.smirl_std_floor must be >= 1e-09, got 0"),
        ("sac.random_interactions", -1, r"sac.random_interactions must be >= 0, got -1"),
        ("sili.scale", float("inf"), r"sili.scale must be a finite number, got inf"),
    ],
)
def test_a_setting_out_of_its_range_is_refused_by_name(path, value, message):
    with pytest.raises(ConfigError, match=message):
        run_config("sili", **{path.replace(".", "__"): value})


def test_the_true_latent_is_part_of_the_policys_input():
    agent = make_agent("sili", "true", horizon=5, hidden=32, strategy_dim=2)
    assert agent.n_latents == 2 and agent.in_dim == 3 + 2 * 2
    assert make_agent("lili", "true", horizon=5, hidden=32, strategy_dim=2).in_dim == 3 + 2


def test_a_discrete_head_predicting_the_raw_targets_has_no_error():
    torch.manual_seed(0)
    model = LatentModel(3, 2, latent_dim=4, hidden=16, kind="discrete", usage_bonus=0.0)
    n, h = 6, 5
    step = torch.tensor([1.0, -2.0, 3.0])
    obs = torch.cumsum(step.expand(n, h + 1, 3), 1)  # s' - s = step on every transition
    rew = torch.full((n, h), 7.0)
    last = model.decoder[-1]
    with torch.no_grad():
        last.weight.zero_()
        last.bias.copy_(torch.cat([step, torch.tensor([7.0])]).repeat(4))  # every head exact
    prev = torch.randn(n, h, 3 + 2 + 1 + 3)
    loss = model.loss(prev, obs[:, :-1], torch.randn(n, h, 2), obs[:, 1:], rew)
    assert float(loss.detach()) == 0.0


ESTIMATOR_BATCH = 8


def _estimator_model(estimator, bonus):
    torch.manual_seed(0)
    m = LatentModel(
        3, 2, latent_dim=2, hidden=4, kind="discrete", estimator=estimator, usage_bonus=bonus
    )
    with torch.no_grad():
        # encoder: category 0 when the previous interaction's first input is positive, else 1
        for p in m.parameters():
            p.zero_()
        m.phi[0].weight[0, 0], m.phi[0].weight[1, 0] = 1.0, -1.0
        m.phi[2].weight.copy_(torch.eye(4))
        m.head.weight[0, 0], m.head.weight[1, 1] = 50.0, 50.0
    return m


def _estimator_data():
    g = torch.Generator().manual_seed(0)
    obs = torch.randn(ESTIMATOR_BATCH, H + 1, 3, generator=g)
    return (
        obs,
        torch.randn(ESTIMATOR_BATCH, H, 2, generator=g),
        torch.randn(ESTIMATOR_BATCH, H, generator=g),
    )


def _previous_interactions(signs):
    prev = torch.zeros(ESTIMATOR_BATCH, H, 9)
    prev[..., 0] = torch.tensor(signs, dtype=torch.float32)[:, None]
    return prev


def _estimator_loss(m, signs, obs, act, rew):
    with torch.no_grad():
        return float(m.loss(_previous_interactions(signs), obs[:, :-1], act, obs[:, 1:], rew))


def test_the_marginal_likelihood_prefers_the_category_whose_head_predicts_the_interaction():
    obs, act, rew = _estimator_data()
    m = _estimator_model("marginal", 0.0)
    with torch.no_grad():  # head 0 predicts the mean target, head 1 is far off
        target = torch.cat([obs[:, 1:] - obs[:, :-1], rew[..., None]], -1).reshape(-1, 4)
        bias = m.decoder[-1].bias.view(2, 4)
        bias[0], bias[1] = target.mean(0), target.mean(0) + 5 * target.std(0)
    assert _estimator_loss(m, [1.0] * ESTIMATOR_BATCH, obs, act, rew) < _estimator_loss(
        m, [-1.0] * ESTIMATOR_BATCH, obs, act, rew
    )


@pytest.mark.parametrize("estimator", ["marginal", "expected"])
def test_the_usage_bonus_prefers_a_batch_spread_over_categories(estimator):
    obs, act, rew = _estimator_data()
    m = _estimator_model(estimator, 0.5)  # every head predicts the same: only the bonus differs
    spread, one = [1.0, -1.0] * (ESTIMATOR_BATCH // 2), [1.0] * ESTIMATOR_BATCH
    assert _estimator_loss(m, spread, obs, act, rew) < _estimator_loss(m, one, obs, act, rew) - 0.1


def _logit_model(estimator, logits):
    torch.manual_seed(0)
    m = LatentModel(
        3, 2, latent_dim=3, hidden=8, kind="discrete", estimator=estimator, usage_bonus=0.0
    )
    with torch.no_grad():
        m.head.weight.zero_()
        m.head.bias.copy_(torch.tensor(logits))
        m.decoder[-1].bias.view(3, 4)[:, -1] += torch.tensor([0.0, 3.0, 9.0])  # distinct errors
    return m


def test_the_gumbel_estimator_pays_one_sampled_categorys_error():
    g = torch.Generator().manual_seed(1)
    prev, obs = torch.randn(1, 5, 9, generator=g), torch.randn(1, 6, 3, generator=g)
    act, rew = torch.randn(1, 5, 2, generator=g), torch.randn(1, 5, generator=g)
    args = (prev, obs[:, :-1], act, obs[:, 1:], rew)
    errs = []
    for k in range(3):  # the expected estimator with a sure encoder: category k's error
        sure = [-100.0] * 3
        sure[k] = 100.0
        errs.append(float(_logit_model("expected", sure).loss(*args).detach()))
    assert len({round(e, 3) for e in errs}) == 3
    gumbel, paid = _logit_model("gumbel", [0.0, 0.0, 0.0]), set()
    for seed in range(5):
        torch.manual_seed(seed)
        loss = float(gumbel.loss(*args).detach())
        paid |= {k for k, e in enumerate(errs) if loss == pytest.approx(e, rel=1e-5)}
        assert loss in [pytest.approx(e, rel=1e-5) for e in errs]
    assert len(paid) > 1  # sampled: equal logits pay more than one category over the seeds


def test_the_target_scale_is_each_outputs_standard_deviation():
    t = torch.stack([torch.tensor([0.0, 5.0, 1.0]), torch.tensor([6.0, 5.0, 1.0 + 1e-6])])[None]
    torch.testing.assert_close(target_scale(t), torch.tensor([6.0 / 2**0.5, 1.0, 1.0]))


def test_the_preact_penalty_is_lambda_times_the_mean_squared_encoder_output():
    torch.manual_seed(0)
    prev, obs = torch.randn(4, 5, 9), torch.randn(4, 6, 3)
    act, rew = torch.randn(4, 5, 2), torch.randn(4, 5)
    model = LatentModel(3, 2, latent_dim=4, hidden=16, kind="continuous", preact_penalty=0.0)
    with torch.no_grad():
        model.head.bias.fill_(-3.0)  # outputs mostly negative: mean and mean square differ
        base = float(model.loss(prev, obs[:, :-1], act, obs[:, 1:], rew))
        model.preact_penalty = 0.5
        penalised = float(model.loss(prev, obs[:, :-1], act, obs[:, 1:], rew))
        expected = 0.5 * float(model.encode_logits(prev).pow(2).mean())
    assert penalised - base == pytest.approx(expected, rel=1e-5)


def test_deterministic_acting_is_the_squashed_mean_of_the_policy():
    torch.manual_seed(0)
    sac = SAC(5, 2, hidden=32)
    with torch.no_grad():
        sac.actor.head.bias[:2].fill_(3.0)  # a mean beyond the box, so tanh shows
    x = torch.randn(16, 5)
    first, second = sac.act(x, deterministic=True), sac.act(x, deterministic=True)
    assert torch.equal(first, second)
    with torch.no_grad():
        torch.testing.assert_close(first, torch.tanh(sac.actor(x)[0]))
    assert first.abs().max() < 1.0


def test_silis_default_b_ramps_from_0_to_one_half_over_250_to_300():
    beta = run_config("sili").agent.sili.beta
    assert beta == Schedule(((250, 0.0), (300, 0.5)))
    assert run_config("sili", sili__beta=0.3).agent.sili.beta == 0.3  # a setting, not fixed


def test_smirl_has_no_latent_and_acts_on_the_state_alone():
    assert run_config("smirl").agent.latent == "none"
    agent = make_agent("smirl", horizon=5, hidden=32)
    assert agent.model is None and agent.in_dim == 3
