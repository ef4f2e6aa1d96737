"""Methods fix what defines them; profiles give the starting settings; bad output directories
are refused by name."""

from __future__ import annotations

import json

import pytest
from fast_settings import FAST_ARGS

from sili_robots.agent import method_config
from sili_robots.cli import main
from sili_robots.errors import ConfigError


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
