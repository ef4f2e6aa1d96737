"""Runs written before the settings were nested (flat config.json, the latent cache and the
add-ons' state at the top of the checkpoint, the true strategy's encoding in the replay, no task
version) resume exactly where they stopped, on the task version they were trained on."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import torch
from agent_helpers import flat_layout
from fast_settings import FAST_ARGS

from sili_robots.cli import main

SETTINGS = ["--set", "latent_filter=0.2", "--set", "stability_distance=posterior"]


def _old_config(run: dict) -> dict:
    """config.json's run in the flat layout of earlier versions, from before task versions."""
    old = flat_layout(run)
    del old["task_id"]
    return {**old, "task": "circle-3"}


def _old_checkpoint(state: dict) -> dict:
    agent = dict(state["agent"])
    latents, addons = agent.pop("latents"), agent.pop("addons")
    agent.update(
        Z=latents["Z"],
        category_map=latents["category_map"],
        posteriors=addons["posteriors"]["P"],
        filter=addons["latent_filter"],
    )
    n = agent["buffer"]["n"]
    agent["buffer"] = {**agent["buffer"], "strategy": np.ones((n, 2), np.float32)}
    return {**state, "agent": agent}


def _metrics(run) -> pd.DataFrame:
    return pd.read_csv(run / "metrics.csv").drop(columns="wall_time")


def test_a_run_saved_in_the_earlier_layout_resumes_exactly(tmp_path):
    common = ["--method", "sili", "--seed", "3", "--checkpoint-every", "4", "--no-progress"]
    whole, part = tmp_path / "whole", tmp_path / "part"
    task = ["--task", "sili/Circle3-v0"]
    assert main(["train", *task, *common, *FAST_ARGS, *SETTINGS, "--interactions", "12",
                 "--out", str(whole)]) == 0  # fmt: skip
    assert main(["train", *task, *common, *FAST_ARGS, *SETTINGS, "--interactions", "8",
                 "--out", str(part)]) == 0  # fmt: skip
    saved = json.loads((part / "config.json").read_text())
    (part / "config.json").write_text(json.dumps({**saved, "run": _old_config(saved["run"])}))
    state = torch.load(part / "checkpoint.pt", weights_only=False)
    torch.save(_old_checkpoint(state), part / "checkpoint.pt")
    assert "task_id" not in json.loads((part / "config.json").read_text())["run"]
    assert main(["train", "--resume", str(part), "--interactions", "12", "--no-progress"]) == 0
    pd.testing.assert_frame_equal(_metrics(part), _metrics(whole))
    resumed = json.loads((part / "config.json").read_text())["run"]
    assert resumed["task_id"] == "sili/Circle3-v0"  # the earlier layout ran the first version
    assert resumed["addons"]["filter"]["eps"] == 0.2 and resumed["agent"]["sac"]["lr"] == 3e-4


def test_a_setting_saved_before_it_existed_reads_as_what_the_run_trained_with():
    """The earliest flat configs lack settings added later; today's defaults are not what
    those runs trained with (bfloat16 where the machine times it faster, merged categories)."""
    from sili_robots.build import make_run_config
    from sili_robots.runs import RunConfig

    run = flat_layout(make_run_config("circle-3", "sili", 0, 10).to_dict())
    for added in ("precision", "latent_merge_threshold", "latent_estimator", "latent_usage_bonus"):
        del run["agent"][added]
    agent = RunConfig.from_dict(run).agent
    assert agent.sac.precision == "float32" and agent.model.merge_threshold == 0.0
    assert (agent.model.estimator, agent.model.usage_bonus) == ("gumbel", 0.0)
    recorded = make_run_config("circle-3", "sili", 0, 10, settings={"sac.precision": "bfloat16"})
    assert RunConfig.from_dict(flat_layout(recorded.to_dict())).agent.sac.precision == "bfloat16"


def test_a_method_without_a_latent_model_reads_as_none_whatever_its_flat_config_says():
    """Earlier flat configs wrote the unused "latent": "discrete" for SAC, Oracle and SMiRL:
    read as today's "none", or a sweep's resume refuses the run as made otherwise."""
    from sili_robots.build import make_run_config
    from sili_robots.runs import RunConfig

    for method in ("sac", "oracle", "smirl"):
        run = flat_layout(make_run_config("circle-3", method, 0, 10).to_dict())
        run["agent"]["latent"] = "discrete"
        assert RunConfig.from_dict(run).agent.latent == "none", method


def test_an_old_config_without_precision_reads_as_float32_where_bfloat16_would_be_chosen(
    monkeypatch,
):
    """The earliest flat configs trained in float32: on a machine whose timing chooses
    bfloat16 they still read as float32 (else a resume rounds otherwise)."""
    from sili_robots.agent import matmul
    from sili_robots.build import make_run_config
    from sili_robots.runs import RunConfig

    run = flat_layout(make_run_config("circle-3", "sili", 0, 10).to_dict())
    del run["agent"]["precision"]
    real = matmul._cached_choice
    monkeypatch.setattr(
        matmul,
        "_cached_choice",
        lambda kind, measure: "bfloat16" if kind == "precision" else real(kind, measure),
    )
    assert matmul.default_precision() == "bfloat16"  # the machine this test stands for
    assert RunConfig.from_dict(run).agent.sac.precision == "float32"
