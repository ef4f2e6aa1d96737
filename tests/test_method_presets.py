"""Methods fix what defines them; profiles give the starting settings; bad output directories
are refused by name."""

from __future__ import annotations

import json

import numpy as np
import pytest
from fast_settings import FAST_ARGS

from sili_robots.agent import method_config
from sili_robots.agent.schedule import Schedule
from sili_robots.build import make_run_config, make_run_env
from sili_robots.cli import main
from sili_robots.errors import ConfigError
from sili_robots.evaluation import load_trained
from sili_robots.wrappers import StrategyFlag


@pytest.mark.parametrize(
    ("method", "setting", "fixed"),
    [
        ("lili", "beta=0.7", "sili.beta = 0.0"),
        ("stable", "beta=0.3", "sili.beta = 1.0"),
        ("sac", 'latent="discrete"', "latent = 'none'"),
        ("oracle", "sili.beta=0.5", "sili.beta = 0.0"),
    ],
)
def test_overriding_what_a_method_fixes_exits_2_naming_method_setting_and_why(
    tmp_path, capsys, method, setting, fixed
):
    args = ["train", "--task", "circle-3", "--method", method, "--set", setting]
    assert main([*args, "--out", str(tmp_path / "r")]) == 2
    err = capsys.readouterr().err
    assert f"method {method!r} fixes {fixed} (" in err and "Traceback" not in err
    assert not (tmp_path / "r").exists()


def test_latent_option_is_refused_for_methods_without_a_latent():
    with pytest.raises(ConfigError, match="method 'sac' fixes latent = 'none'"):
        method_config("sac", latent="continuous")
    assert method_config("sac", task_latent="continuous").latent == "none"  # the task's default
    for method in ("sili", "lili", "stable"):  # the methods defined by a latent need one
        with pytest.raises(ConfigError, match=f"method '{method}' learns a latent .* 'none'"):
            method_config(method, latent="none")  # worded for the API and the CLI alike:
    with pytest.raises(ConfigError, match=r"partial or true, or method sac for no latent$"):
        method_config("sili", latent="none")
    with pytest.raises(ConfigError, match=r"method 'lili' learns a latent .* choose discrete"):
        method_config("lili", latent="partial")  # asked for: refused, never swapped silently
    assert method_config("lili", task_latent="partial").latent == "discrete"  # task's default
    assert method_config("sili", task_latent="partial").latent == "partial"


def test_paper_profile_writes_the_papers_values(tmp_path):
    out = tmp_path / "paper"
    args = ["train", "--task", "circle-3", "--profile", "paper", "--interactions", "4"]
    assert main([*args, *FAST_ARGS, "--out", str(out), "--no-progress"]) == 0
    agent = json.loads((out / "config.json").read_text())["run"]["agent"]
    assert agent["profile"] == "paper"
    assert agent["latent"] == "discrete" and agent["model"]["dim"] == 10
    assert agent["model"]["estimator"] == "gumbel" and agent["model"]["sample"] is True
    assert agent["sili"]["beta"] == 0.5 and agent["sili"]["credit"] == "per_step"
    assert agent["model"]["usage_bonus"] == 0.0 and agent["model"]["merge_threshold"] == 0.0
    package = method_config("sili")
    assert package.profile == "package" and package.model.estimator == "expected"
    assert method_config("sili", profile="paper").hidden == 256
    continuous = method_config("sili", "continuous", profile="paper")
    assert continuous.model.preact_penalty == 0.0  # the package adds 1e-3 (README's table)
    assert method_config("sili", "continuous").model.preact_penalty == 1e-3
    # the paper's continuous z is the encoder's raw output, the package's its tanh; a discrete
    # run records the setting unchanged (it has no use for it)
    assert continuous.model.squash is False and method_config("sili", "continuous").model.squash
    assert method_config("sili", profile="paper").model.squash is True


def test_the_paper_profile_keeps_float32_products_where_a_machine_would_choose_bfloat16(
    monkeypatch,
):
    from sili_robots.agent import matmul

    monkeypatch.setattr(matmul, "_cached_choice", lambda kind, measure: "bfloat16")
    assert method_config("sili").sac.precision == "bfloat16"  # such a machine's own choice
    assert method_config("sili", profile="paper").sac.precision == "float32"  # the authors'


def test_a_continuous_latent_is_the_raw_encoder_output_unless_squashed():
    import torch

    from sili_robots.agent.config import AgentConfig
    from sili_robots.agent.latent import LatentModel

    traj = torch.randn(6, 5, 3 + 2 + 1 + 3)
    for squash in (True, False):
        torch.manual_seed(0)
        model = LatentModel(3, 2, latent_dim=4, hidden=16, kind="continuous", squash=squash)
        with torch.no_grad():
            model.head.bias.fill_(3.0)  # outputs beyond tanh's range
            raw = model.encode_logits(traj)
            z = model.encode(traj)
        torch.testing.assert_close(z, torch.tanh(raw) if squash else raw)
        assert (z.abs().max() > 1.0) is not squash
    recorded = method_config("sili", "continuous", profile="paper").to_dict()
    del recorded["model"]["squash"]  # a run saved before the setting: trained with tanh
    assert AgentConfig.from_dict(recorded).model.squash is True


def test_a_paper_profile_agent_learns_its_continuous_latents_unsquashed():
    import torch

    from sili_robots.build import build_agent, make_run_config, make_run_env

    models = {}
    for profile in ("package", "paper"):
        cfg = make_run_config(
            "circle-continuous", "sili", 0, 5, profile=profile, settings={"hidden": 16}
        )
        env = make_run_env(cfg)
        models[profile] = build_agent(cfg, env).model
        env.close()
    assert models["package"].squash is True and models["paper"].squash is False
    model = models["paper"]
    o, a, h = model.out_dim - 1, 2, 6
    torch.manual_seed(0)
    prev, obs = torch.randn(4, h, 2 * o + a + 1), torch.randn(4, h + 1, o)
    act, rew = torch.randn(4, h, a), torch.randn(4, h)
    with torch.no_grad():
        model.head.bias.fill_(3.0)  # outputs beyond tanh's range
        raw = model.loss(prev, obs[:, :-1], act, obs[:, 1:], rew)
        model.squash = True
        squashed = model.loss(prev, obs[:, :-1], act, obs[:, 1:], rew)
    assert not torch.isclose(raw, squashed)  # the objective reads the raw output


def test_an_output_directory_that_cannot_be_created_exits_2_naming_it(capsys):
    out = "/proc/forbidden/x"
    args = ["train", "--task", "circle-3", "--interactions", "2", "--out", out]
    assert main([*args, *FAST_ARGS, "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert f"cannot create the run directory {out}" in err and "Traceback" not in err


def test_method_and_profile_are_chosen_not_overridden():
    with pytest.raises(ConfigError, match="profile is not a setting to override"):
        method_config("sili", overrides={"profile": "paper"})
    with pytest.raises(ConfigError, match="method is not a setting to override"):
        method_config("lili", overrides={"method": "sili"})


def test_sili_starts_from_the_profile_its_task_registers():
    from sili_robots.build import make_run_config
    from sili_robots.tasks import TASKS

    # Driving registers the paper's profile (the grid's choice); every other task the package's
    assert {name for name, spec in TASKS.items() if spec.sili_profile != "package"} == {"driving"}
    assert make_run_config("driving", "sili").agent.profile == "paper"
    assert make_run_config("driving", "sili").agent.model.estimator == "gumbel"
    assert make_run_config("driving", "sac").agent.profile == "package"
    assert make_run_config("circle-3", "sili").agent.profile == "package"
    assert make_run_config("driving", "sili", profile="package").agent.profile == "package"


def test_a_sweep_records_each_tasks_sili_profile_and_keeps_it_on_resume():
    from sili_robots.sweep import SweepSpec, expand

    spec = SweepSpec(
        tasks=["driving", "circle-3"], methods=["sili", "lili"], seeds=[0], interactions=5
    )
    assert spec.sili_profiles == {"driving": "paper", "circle-3": "package"}
    names = [r.name for r in expand(spec)]
    assert names == [
        "driving__sili-paper-b0.5__s0",
        "driving__lili__s0",
        "circle-3__sili-bschedule__s0",
        "circle-3__lili__s0",
    ]
    # recorded before Driving's default moved: resumed as it was planned
    older = {**spec.to_dict(), "sili_profiles": {"driving": "package", "circle-3": "package"}}
    assert expand(SweepSpec.from_dict(older))[0].name == "driving__sili-bschedule__s0"
    # recorded before profiles existed: the package's
    before = {k: v for k, v in spec.to_dict().items() if k not in ("profile", "sili_profiles")}
    assert SweepSpec.from_dict(before).profile == "package"
    assert expand(SweepSpec.from_dict(before))[0].name == "driving__sili-bschedule__s0"


@pytest.mark.parametrize("method", ["oracle", "sac", "smirl", "lili"])
def test_oracle_alone_observes_the_true_strategy(tmp_path, method):
    """Oracle's policy reads z's encoding after the task's observation; no other method sees it."""
    out = tmp_path / method
    args = ["train", "--task", "circle-3", "--method", method, "--interactions", "2"]
    assert main([*args, "--out", str(out), *FAST_ARGS, "--no-progress"]) == 0
    _, env, agent, _ = load_trained(out)
    task = env.unwrapped
    extra = task.strategy_dim if method == "oracle" else 0
    assert agent.obs_dim == task.observation_space.shape[0] + extra
    obs, info = env.reset(seed=0)
    assert obs.shape == (agent.obs_dim,)
    if extra:
        np.testing.assert_array_equal(obs[-extra:], info["strategy"])


def test_a_setting_the_method_never_reads_is_recorded_with_a_note(tmp_path, capsys):
    from sili_robots.agent.methods import unused_settings

    assert unused_settings(method_config("sac"), ["model.dim", "sac.lr"]) == {
        "model.dim": "it learns no latent model (latent 'none')"
    }
    assert unused_settings(method_config("sili"), ["model.dim"]) == {}
    floor = ["sili.smirl_std_floor"]
    assert "sili.smirl_std_floor" in unused_settings(method_config("lili"), floor)
    assert unused_settings(method_config("smirl"), floor) == {}
    credit = ["sili.scale", "sili.credit"]
    for method in ("lili", "sac", "oracle"):  # b = 0: no stability term to scale
        assert set(unused_settings(method_config(method), credit)) == set(credit)
    never = method_config("sili", overrides={"sili.beta": Schedule(((0, 0), (10, 0)))})
    assert set(unused_settings(never, credit)) == set(credit)
    assert unused_settings(method_config("smirl"), credit)
    for method in ("sili", "stable"):
        assert unused_settings(method_config(method), credit) == {}
    delayed = method_config("sili", overrides={"sili.beta": Schedule(((0, 0), (10, 0.5)))})
    assert unused_settings(delayed, credit) == {}
    per_step = method_config("sili", overrides={"sili.credit": "per_step"})
    assert list(unused_settings(per_step, credit)) == ["sili.scale"]  # paid unscaled
    discrete_only = [
        "model.estimator",
        "model.sample",
        "model.usage_bonus",
        "model.merge_threshold",
    ]
    continuous_only = ["model.squash", "model.preact_penalty"]
    continuous = method_config("sili", latent="continuous")
    assert set(unused_settings(continuous, discrete_only + continuous_only)) == set(discrete_only)
    discrete = method_config("sili")
    assert set(unused_settings(discrete, discrete_only + continuous_only)) == set(continuous_only)
    gumbel = method_config("sili", overrides={"model.estimator": "gumbel"})
    assert list(unused_settings(gumbel, discrete_only)) == ["model.usage_bonus"]
    out = tmp_path / "sac"
    args = ["train", "--task", "circle-3", "--method", "sac", "--interactions", "1", *FAST_ARGS]
    assert main([*args, "--set", "model.dim=4", "--out", str(out), "--no-progress"]) == 0
    note = "sili train: note: --set model.dim does nothing here: it learns no latent model"
    assert note in capsys.readouterr().err
    assert json.loads((out / "config.json").read_text())["run"]["agent"]["model"]["dim"] == 4
    sweep = ["sweep", "--tasks", "circle-3", "--methods", "sili,sac,oracle", "--seeds", "0-1"]
    assert main([*sweep, "--set", "model.dim=4", "--out", str(tmp_path / "s"), "--dry-run"]) == 0
    err = capsys.readouterr().err
    assert "note: --set model.dim does nothing for sac on circle-3; oracle on circle-3: it" in err
    two = ["sweep", "--tasks", "circle-3,speaker-listener", "--methods", "sili", "--seeds", "0"]
    assert main([*two, "--set", "model.dim=4", "--out", str(tmp_path / "t"), "--dry-run"]) == 0
    err = capsys.readouterr().err  # SILI learns none on Speaker-Listener alone (partial)
    assert "note: --set model.dim does nothing for sili on speaker-listener: it learns" in err


def test_a_setting_that_departs_from_the_paper_profile_is_noted(capsys, tmp_path):
    """A run of --profile paper is recorded (and named, and labelled) as that profile: one
    given another value than the paper's is told so; the paper's own value, or the package
    profile, says nothing."""
    from sili_robots.agent.methods import paper_departures

    paper = method_config("sili", profile="paper", overrides={"model.estimator": "expected"})
    assert paper_departures(paper, ["model.estimator", "hidden"]) == {"model.estimator": "gumbel"}
    assert paper_departures(method_config("sili", overrides={"hidden": 32}), ["hidden"]) == {}
    held = method_config("sili", profile="paper", overrides={"sili.beta": Schedule(((0, 0.5),))})
    assert paper_departures(held, ["sili.beta"]) == {}  # a schedule holding the paper's b
    sac = method_config("sac", profile="paper", overrides={"model.dim": 4})
    assert paper_departures(sac, ["model.dim"]) == {}  # a setting it never reads
    args = ["train", "--task", "circle-3", "--method", "sili", "--profile", "paper"]
    args += ["--interactions", "1", "--no-progress", "--set", "model.estimator=gumbel"]
    assert main([*args, "--set", "hidden=32", "--out", str(tmp_path / "r")]) == 0
    err = capsys.readouterr().err
    assert "note: --set hidden departs from the paper profile (hidden 256 there)" in err
    assert "estimator" not in err
    sweep = ["sweep", "--tasks", "circle-3,driving", "--methods", "sili,sac", "--seeds", "0"]
    assert main([*sweep, "--set", "hidden=32", "--out", str(tmp_path / "s"), "--dry-run"]) == 0
    err = capsys.readouterr().err  # SILI starts from the paper profile on Driving alone
    assert (
        "--set hidden departs from the paper profile (hidden 256 there) for sili on driving:" in err
    )


def test_an_addon_setting_that_does_nothing_is_noted_and_its_addon_not_built(capsys, tmp_path):
    """Settings of a switched-off add-on, a fraction of a batch that rounds to no draw, and a
    stability distance where there is no stability term were silently ignored (the last one
    computing hindsight posteriors on every interaction all the same)."""
    from sili_robots.addons import build_addons
    from sili_robots.build import make_run_config

    def notes(method: str, **settings) -> dict[str, str]:
        cfg = make_run_config("circle-3", method, 0, 10, settings=settings)
        return cfg.unread_settings(settings)

    assert notes("sili", **{"addons.filter.noise": 0.5, "addons.recent.interactions": 5}) == {
        "addons.filter.noise": "the latent filter is off (addons.filter.eps 0)",
        "addons.recent.interactions": "recent batches are off (addons.recent.fraction 0)",
    }
    assert notes("sili", **{"addons.filter.eps": 0.1, "addons.filter.noise": 0.5}) == {}
    small = {"addons.recent.fraction": 0.03, "addons.change_fraction": 0.01}
    assert notes("sili", **small) == {
        "addons.recent.fraction": "0.03 of a batch of 16 rounds to no draw",
        "addons.change_fraction": "0.01 of a batch of 32 rounds to no draw",
    }
    assert notes("sili", **{"addons.recent.fraction": 0.25}) == {}
    hindsight = {"addons.stability_distance": "hindsight"}
    lili_note = "LILI has no stability reward (b = 0) to count changes for"
    assert notes("lili", **hindsight) == {"addons.stability_distance": lili_note}
    assert notes("sili", **hindsight) == {}
    b0 = {**hindsight, "sili.beta": 0.0}  # its metrics' stability column reads the distance
    assert notes("sili", **b0) == {}
    sili_b0 = make_run_config("circle-3", "sili", 0, 10, settings=b0)
    assert [a.name for a in build_addons(sili_b0.addons, sili_b0.agent)] == ["posteriors"]
    lili = make_run_config("circle-3", "lili", 0, 10, settings=hindsight)
    assert build_addons(lili.addons, lili.agent) == []  # nothing it would compute is read
    both = make_run_config(
        "circle-3", "lili", 0, 10, settings={**hindsight, "addons.change_fraction": 0.25}
    )
    assert [a.name for a in build_addons(both.addons, both.agent)] == ["posteriors"]
    args = ["train", "--task", "circle-3", "--method", "sili", "--interactions", "1", *FAST_ARGS]
    out = str(tmp_path / "r")
    assert main([*args, "--set", "addons.filter.noise=0.5", "--out", out, "--no-progress"]) == 0
    assert "note: --set addons.filter.noise does nothing here: the latent filter is off" in (
        capsys.readouterr().err
    )


@pytest.mark.parametrize("method", ["sili", "stable"])
def test_a_partial_latent_run_observes_the_strategy_flag(method):
    """SILI and Stable with the partial latent (Speaker-Listener's default) read their stability
    from the flag the observation ends with: without it, they would read the time fraction."""
    cfg = make_run_config("speaker-listener", method, interactions=2)
    assert cfg.agent.latent == "partial"
    env = make_run_env(cfg)
    try:
        assert isinstance(env, StrategyFlag)
        assert env.observation_space.shape[0] == env.unwrapped.observation_space.shape[0] + 1
    finally:
        env.close()
