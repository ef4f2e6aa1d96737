"""The within-interaction latent filter (``latent_filter``): prior from the encoder, evidence from
the decoder heads, the per-step latents the policy and the critic see, and runs that use it."""

import numpy as np
import pytest
import torch
from agent_helpers import make_agent, run_config

from sili_robots.addons.filter_math import (
    LOGLIK_FLOOR,
    filtered_categories,
    log_prior,
    medoid_candidates,
    target_norm,
)
from sili_robots.addons.latent_filter import LatentFilter
from sili_robots.errors import ConfigError

H = 5


EPS = 0.2


def _agent(latent="discrete", latent_dim=4, **kw):
    return make_agent(
        "sili",
        latent,
        obs_dim=3,
        act_dim=2,
        horizon=H,
        strategy_dim=2,
        seed=0,
        latent_dim=latent_dim,
        hidden=32,
        batch_interactions=4,
        batch_steps=H,
        **{"latent_filter": EPS, **kw},
    )


def _filter(agent) -> LatentFilter:
    return agent.addon(LatentFilter)


def _constant_heads(agent):
    """Category k predicts standing still and reward 5k on every step."""
    with torch.no_grad():
        last = agent.model.decoder[-1]
        last.weight.zero_()
        last.bias.zero_()
        last.bias.view(4, 4)[:, -1] = torch.tensor([0.0, 5.0, 10.0, 15.0])


def _store(agent, reward, obs=None):
    obs = np.ones((H + 1, 3), np.float32) if obs is None else obs
    agent.observe_interaction(
        obs,
        np.zeros((H, 2), np.float32),
        np.full(H, reward, np.float32),
        obs[0],
        0.0,
        {"strategy": np.zeros(2, np.float32)},
        refresh=False,
    )


def test_log_prior_puts_one_minus_eps_on_the_encoders_category():
    in_use = np.array([0, 2])
    logp = log_prior(np.array([[0, 0, 1, 0], [0, 0, 0, 0]], np.float32), in_use, 0.1)
    np.testing.assert_allclose(np.exp(logp[0]), [0.05, 0, 0.95, 0])
    np.testing.assert_allclose(np.exp(logp[1]), [0.5, 0, 0.5, 0])  # no prediction: uniform
    assert np.isneginf(logp[:, [1, 3]]).all()


def test_filtered_category_switches_once_the_evidence_outweighs_the_prior():
    logp = np.log(np.array([[0.9, 0.1]]))  # log odds 2.2 for category 0
    ll = np.array([[[-1.0, 0.0]] * 4])  # each step favours category 1 by 1 nat
    # before each step and after the last: 2.2, 1.2, 0.2 for 0, then -0.8, -1.8
    np.testing.assert_array_equal(filtered_categories(logp, ll)[0], [0, 0, 0, 1, 1])


def test_policy_acts_on_the_corrected_latent_within_the_interaction():
    agent = _agent()
    _constant_heads(agent)
    for reward in (0.0, 5.0, 0.0, 5.0):  # categories 0 and 1 shown, so both are in use
        _store(agent, reward)
    agent.Z = np.eye(4, dtype=np.float32)[[0, 0, 1, 0, 0]]  # z^4 (the next one) predicts 0
    agent.refresh_latents = lambda: None  # keep the hand-set Z; the filter is what is tested
    f = _filter(agent)
    f._refresh()
    np.testing.assert_array_equal(f.in_use, [0, 1])
    # the heads fit exactly: the noise scale is its floor, so one step decides
    np.testing.assert_array_equal(f.ZF[1], [0, 1, 1, 1, 1, 1])  # predicted 0, showed 1
    np.testing.assert_array_equal(f.ZF[2], [1, 0, 0, 0, 0, 0])  # predicted 1, showed 0
    np.testing.assert_array_equal(f.ZF[3], [0, 1, 1, 1, 1, 1])
    f.begin_interaction()
    obs = np.ones(3, np.float32)
    z_slot = slice(3, 7)
    np.testing.assert_array_equal(agent.policy_input(obs)[z_slot], [1, 0, 0, 0])
    agent.observe_step(obs, np.zeros(2, np.float32), 5.0, obs)  # the reward of category 1
    np.testing.assert_array_equal(agent.policy_input(obs)[z_slot], [0, 1, 0, 0])
    # the stored interaction's z^j (not the live one) when asked for by index
    np.testing.assert_array_equal(agent.policy_input(obs, j=4)[z_slot], [1, 0, 0, 0])
    assert f._ll[0] == pytest.approx(-LOGLIK_FLOOR)  # one step: floored evidence


def test_the_filter_starts_at_the_refresh_that_reaches_its_start():
    """addons.filter.start=4: not at the refresh after 3 stored interactions, at the one after
    4 (the latents are recomputed then, and the filter with them)."""
    agent = _agent(latent_filter_start=4)
    for reward in (0.0, 5.0, 0.0):
        _store(agent, reward)
    agent.refresh_latents()
    assert _filter(agent).scale is None
    _store(agent, 5.0)
    agent.refresh_latents()
    assert _filter(agent).scale is not None


def test_filter_does_not_act_before_the_first_refresh():
    agent = _agent()
    _store(agent, 5.0)
    f = _filter(agent)
    assert f.scale is None
    np.testing.assert_array_equal(f.ZF, np.full((1, H + 1), -1))
    agent.observe_step(np.ones(3, np.float32), np.zeros(2, np.float32), 5.0, np.ones(3))
    np.testing.assert_array_equal(agent.policy_input(np.ones(3, np.float32))[3:7], agent.Z[1])


def test_rl_batches_use_the_per_step_latents_and_the_encoders_at_the_boundary():
    agent = _agent()
    rng = np.random.default_rng(0)
    for _ in range(4):
        _store(agent, 0.0, rng.normal(size=(H + 1, 3)).astype(np.float32))
    agent.Z = np.eye(4, dtype=np.float32)[[0, 1, 2, 3, 0]]
    f = _filter(agent)
    f.ZF = rng.integers(0, 4, (4, H + 1)).astype(np.int16)
    f.ZF[0] = -1  # filter not running: the encoder's z^0 stands
    x, _, _, x2 = agent.sample_batches(40, beta=0.5)
    x, x2 = x.reshape(-1, x.shape[-1]).numpy(), x2.reshape(-1, x2.shape[-1]).numpy()
    b, eye = agent.buffer, np.eye(4)
    seen_boundary = seen_inside = 0
    for row, row2 in zip(x, x2, strict=True):
        j, t = (int(i[0]) for i in np.where((b.obs[: b.n, :-1] == row[:3]).all(-1)))
        acted = agent.Z[j] if j == 0 else eye[f.ZF[j, t]]
        np.testing.assert_array_equal(row[3:7], acted)
        np.testing.assert_array_equal(row[7:11], agent.Z[j - 1] if j else np.zeros(4))
        if t == H - 1:
            seen_boundary += 1
            np.testing.assert_array_equal(row2[3:7], agent.Z[j + 1])  # the encoder's z^{j+1}
            np.testing.assert_array_equal(row2[7:11], agent.Z[j])  # and its z^j as previous
        else:
            seen_inside += 1
            nxt = agent.Z[j] if j == 0 else eye[f.ZF[j, t + 1]]
            np.testing.assert_array_equal(row2[3:7], nxt)
    assert seen_boundary and seen_inside


def test_filter_state_survives_a_checkpoint():
    agent = _agent()
    _constant_heads(agent)
    for reward in (0.0, 5.0, 0.0):
        _store(agent, reward)
    agent.Z = np.eye(4, dtype=np.float32)[[0, 0, 1, 0]]
    f = _filter(agent)
    f._refresh()
    other = _agent()
    other.load_state_dict(agent.state_dict())
    g = _filter(other)
    np.testing.assert_array_equal(g.ZF, f.ZF)
    np.testing.assert_array_equal(g.in_use, f.in_use)
    torch.testing.assert_close(g.scale, f.scale)


@pytest.mark.parametrize(
    "settings, message",
    [
        ({"latent_filter": 1.0}, r"addons\.filter\.eps must be in \[0, 0\.999999\], got 1\.0"),
        ({"latent_filter": 0.1, "latent": "partial"}, "add-on latent_filter needs learned latents"),
        ({"latent_filter": 0.1, "latent_filter_start": -1}, "addons.filter.start must be >= 0"),
        ({"latent_filter": 0.1, "latent_filter_noise": -0.5}, "addons.filter.noise must be >= 0"),
    ],
)
def test_bad_filter_settings_are_named(settings, message):
    settings = dict(settings)
    latent = settings.pop("latent", "discrete")
    with pytest.raises(ConfigError, match=message):
        run_config("sili", latent, **settings)
    with pytest.raises(ConfigError, match="add-on latent_filter needs learned latents"):
        run_config("sac", latent_filter=0.1)
    assert run_config("sili", "continuous", latent_filter=0.1).addons.filter.eps == 0.1


# ---------------------------------------------------------------- continuous latents


def _continuous_agent(**kw):
    return _agent("continuous", latent_dim=2, **kw)


def _reward_from_z(agent):
    """D(s, a, z) predicts standing still and reward 10 z_0 (z_0 in [-1, 1]), in the units the
    continuous decoder is trained in: targets standardised by the replay's mean and std."""
    b = agent.buffer
    mean, std = (
        float(x[-1])
        for x in target_norm(torch.from_numpy(b.obs[: b.n]), torch.from_numpy(b.rew[: b.n]))
    )
    slope, offset = 10.0 / std, -mean / std  # standardised reward = slope * z_0 + offset
    with torch.no_grad():
        first, second, last = agent.model.decoder[0], agent.model.decoder[2], agent.model.decoder[4]
        for layer in (first, second, last):
            layer.weight.zero_()
            layer.bias.zero_()
        first.weight[0, 3 + 2] = 1.0  # input (s, a, z): z_0 is input 5
        first.bias[0] = 2.0  # z_0 + 2 > 0 passes the ReLUs unchanged
        second.weight[0, 0] = 1.0
        last.weight[-1, 0] = slope
        last.bias[-1] = offset - 2.0 * slope


def test_medoid_candidates_are_encoder_latents_one_per_cluster():
    rng = np.random.default_rng(0)
    centres = np.array([[0.8, 0.0], [-0.5, 0.5], [0.0, -0.9]], np.float32)
    z = (centres[rng.integers(0, 3, 300)] + 0.02 * rng.normal(size=(300, 2))).astype(np.float32)
    cands = medoid_candidates(z, 8, seed=3)
    assert 3 <= len(cands) <= 8
    assert all((z == c).all(-1).any() for c in cands)  # actual rows, never a centroid
    nearest = np.linalg.norm(cands[:, None] - centres[None], axis=-1).argmin(-1)
    assert set(nearest) == {0, 1, 2}  # every strategy has a candidate
    np.testing.assert_array_equal(cands, medoid_candidates(z, 8, seed=3))  # reproducible
    assert len(medoid_candidates(z[:1].repeat(5, 0), 8, seed=0)) == 1  # no duplicates


def _stored_continuous_agent(**kw):
    """Four interactions stored with rewards 0, 5, -5, 5, played on latents 0 (no history),
    -0.5, 0.5, 0.5: the first and last predicted right, the two between wrong; z^4 (the next)
    predicts 5."""
    agent = _continuous_agent(**kw)
    for reward in (0.0, 5.0, -5.0, 5.0):
        _store(agent, reward)
    _reward_from_z(agent)
    agent.Z = np.array([[0, 0], [-0.5, 0], [0.5, 0], [0.5, 0], [0.5, 0]], np.float32)
    return agent


def test_continuous_filter_switches_to_the_latent_that_explains_the_steps():
    agent = _stored_continuous_agent()
    f = _filter(agent)
    f._refresh()
    np.testing.assert_array_equal(f.candidates, [[-0.5, 0], [0.5, 0]])
    # residual scale of the reward, under the best candidate of each interaction: it explains
    # every one but the first (reward 0, off by 5 under either candidate)
    scale = float(f.scale[-1])
    assert scale == pytest.approx(5 * np.sqrt(1 / 4), rel=1e-5)
    per_step = min(0.5 * (10 / scale) ** 2, LOGLIK_FLOOR)  # evidence against z^j per step
    prior_odds = np.log((1 - EPS) / (EPS / 2))
    switch = int(np.ceil(prior_odds / per_step + 1e-9))  # steps until the evidence wins
    assert 0 < switch < H
    np.testing.assert_array_equal(f.ZF[0], [-1] * (H + 1))  # right all along
    np.testing.assert_array_equal(f.ZF[1], [-1] * switch + [1] * (H + 1 - switch))
    np.testing.assert_array_equal(f.ZF[2], [-1] * switch + [0] * (H + 1 - switch))
    # a candidate that predicts the same as z^j (0.5) never takes over from it
    np.testing.assert_array_equal(f.ZF[3], [-1] * (H + 1))

    f.begin_interaction()
    obs, act = np.ones(3, np.float32), np.zeros(2, np.float32)
    z_slot = slice(3, 5)
    np.testing.assert_array_equal(agent.policy_input(obs)[z_slot], [0.5, 0])  # the encoder's
    for _ in range(switch):
        np.testing.assert_array_equal(agent.policy_input(obs)[z_slot], [0.5, 0])
        agent.observe_step(obs, act, -5.0, obs)  # the reward of z_0 = -0.5
    np.testing.assert_array_equal(agent.policy_input(obs)[z_slot], [-0.5, 0])
    np.testing.assert_array_equal(agent.policy_input(obs, j=1)[z_slot], [-0.5, 0])  # stored z^1
    for _ in range(H - switch):
        agent.observe_step(obs, act, -5.0, obs)
    stats = agent.observe_interaction(
        np.ones((H + 1, 3), np.float32),
        np.zeros((H, 2), np.float32),
        np.full(H, -5.0, np.float32),
        obs,
        0.0,
        {},
        refresh=False,
    )
    assert stats.extra["filter_step"] == switch  # the step it first acted on another latent
    np.testing.assert_array_equal(f.ZF[4], [-1] * switch + [0] * (H + 1 - switch))


def test_continuous_rl_batches_put_the_candidate_acted_on_in_the_z_slot():
    agent = _stored_continuous_agent()
    f = _filter(agent)
    f._refresh()
    rng = np.random.default_rng(0)
    agent.buffer.obs[: agent.buffer.n] = rng.normal(size=agent.buffer.obs[:4].shape)
    f.ZF = rng.integers(-1, 2, (4, H + 1)).astype(np.int16)
    x, _, _, x2 = agent.sample_batches(40, beta=0.0)
    x, x2 = x.reshape(-1, x.shape[-1]).numpy(), x2.reshape(-1, x2.shape[-1]).numpy()
    b = agent.buffer
    seen = {-1: 0, 0: 0, 1: 0}
    for row, row2 in zip(x, x2, strict=True):
        j, t = (int(i[0]) for i in np.where((b.obs[: b.n, :-1] == row[:3]).all(-1)))
        c = int(f.ZF[j, t])
        seen[c] += 1
        np.testing.assert_array_equal(row[3:5], agent.Z[j] if c < 0 else f.candidates[c])
        if t == H - 1:
            np.testing.assert_array_equal(row2[3:5], agent.Z[j + 1])
    assert all(seen.values())


@pytest.mark.parametrize("start, running", [(0, True), (100, False)])
def test_a_checkpoint_without_the_filter_starts_it_as_a_run_would(start, running):
    plain = _stored_continuous_agent(latent_filter=0.0)
    assert "latent_filter" not in plain.state_dict()["addons"]  # saved without the filter
    agent = _continuous_agent(latent_filter_start=start)
    agent.load_state_dict(plain.state_dict())
    f = _filter(agent)
    assert len(f.ZF) == 4
    if running:
        reference = _filter(_stored_continuous_agent())
        reference._refresh()
        np.testing.assert_array_equal(f.ZF, reference.ZF)
        np.testing.assert_array_equal(f.candidates, reference.candidates)
        assert f._logp is not None
    else:
        assert f.scale is None and (f.ZF == -1).all()
        agent.refresh_latents()  # still before the start: the filter stays off
        assert f.scale is None
        x, _, _, _ = agent.sample_batches(2, beta=0.0)  # RL batches on the encoder's latents
        z_rows = {tuple(r) for r in agent.Z[:4]}
        assert {tuple(r) for r in x.reshape(-1, x.shape[-1])[:, 3:5].numpy()} <= z_rows
    restored = _continuous_agent(latent_filter_start=start)
    restored.load_state_dict(agent.state_dict())
    np.testing.assert_array_equal(_filter(restored).ZF, f.ZF)
    np.testing.assert_array_equal(_filter(restored).candidates, f.candidates)


def test_a_broader_noise_scale_needs_more_steps_of_evidence():
    """``latent_filter_noise``: the scale is that fraction of the targets' std, so the same wrong
    interaction takes longer to overturn z^j, and an error as large as a strategy's still does."""
    agent = _stored_continuous_agent(latent_filter_noise=1.5)
    f = _filter(agent)
    f._refresh()
    b = agent.buffer
    _, std = target_norm(torch.from_numpy(b.obs[: b.n]), torch.from_numpy(b.rew[: b.n]))
    torch.testing.assert_close(f.scale, 1.5 * std)
    per_step = min(0.5 * (10 / float(f.scale[-1])) ** 2, LOGLIK_FLOOR)
    switch = int(np.ceil(np.log((1 - EPS) / (EPS / 2)) / per_step + 1e-9))
    assert switch == 2  # one step with the residual scale (the test above), two here
    np.testing.assert_array_equal(f.ZF[1], [-1] * switch + [1] * (H + 1 - switch))
    np.testing.assert_array_equal(f.ZF[3], [-1] * (H + 1))
    # played live, step by step, interaction 1 gathers the same evidence: it switches alike
    agent.Z[b.n] = agent.Z[1]
    f.begin_interaction()
    for t in range(H):
        agent.observe_step(b.obs[1, t], b.act[1, t], float(b.rew[1, t]), b.obs[1, t + 1])
    assert f._cats == f.ZF[1].tolist()


def test_addons_wired_into_a_trained_agent_start_from_its_stored_interactions():
    """attach_addon on an agent that has played: the filter and the hindsight posteriors build
    their state for the stored interactions (they failed on the next one with an IndexError)."""
    from sili_robots.addons.posteriors import HindsightPosteriors

    agent = _agent(latent_filter=0.0)
    for r in range(6):
        _store(agent, float(r))
    agent.refresh_latents()
    agent.attach_addon(LatentFilter(EPS))
    agent.attach_addon(HindsightPosteriors("hindsight", 0.5))
    assert _filter(agent).ZF.shape == (6, H + 1) and _filter(agent).scale is not None
    assert agent.addon(HindsightPosteriors).P.shape == (6, agent.zdim)
    _store(agent, 1.0)
    agent.update(7)
    assert _filter(agent).ZF.shape[0] == agent.addon(HindsightPosteriors).P.shape[0] == 7


def test_the_filter_keeps_the_no_history_latent_until_evidence_tells_the_options_apart():
    """At a game's start z^j is all zeros, a uniform prior over the categories in use: the
    filter acted on the lowest-numbered one before any step, a strategy it had no reason for."""
    from sili_robots.addons.filter_math import decided, log_prior

    assert decided(log_prior(np.zeros((1, 4)), np.array([1, 3]), EPS)).tolist() == [-1]
    assert decided(log_prior(np.eye(4)[[3]], np.array([1, 3]), EPS)).tolist() == [3]
    agent = _agent()
    _constant_heads(agent)
    for r in (0.0, 5.0, 10.0, 15.0) * 2:
        _store(agent, r)
    agent.refresh_latents()
    assert _filter(agent).scale is not None  # running
    agent.begin_game({"strategy": np.zeros(2, np.float32)})
    assert _filter(agent).acted == [-1]  # no evidence yet: the encoder's "no history"
    obs = np.ones(3, np.float32)
    agent.observe_step(obs, np.zeros(2, np.float32), 10.0, obs)  # evidence: a category in use
    assert _filter(agent).acted[0] == -1 and _filter(agent).acted[1] in _filter(agent).in_use
    assert _filter(agent)._rows(np.array([0]))[0, 0] == -1  # the game's first, as replayed
