"""``sili train`` / ``sili eval`` end to end: run directories, bad input, kill and resume."""

import hashlib
import io
import json
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import torch
from cli_helpers import sili as _sili
from disk_helpers import file_size_limit
from fast_settings import FAST_AGENT, FAST_ARGS

from sili_robots import SILI, training
from sili_robots.addons import LatentFilter
from sili_robots.cli import main
from sili_robots.errors import ConfigError
from sili_robots.evaluation import AgentFeedback, evaluate, load_trained
from sili_robots.metrics import read_metrics
from sili_robots.provenance import code_revision
from sili_robots.runs import (
    load_checkpoint,
    read_config,
    record_continuation,
    save_checkpoint,
    set_target,
)
from sili_robots.sweep.state import run_state
from sili_robots.training import extend, resume, write_summary

FAST = [*FAST_ARGS, "--no-progress"]


def test_train_writes_a_complete_run_and_eval_reads_it(tmp_path):
    out = tmp_path / "run"
    res = _sili(
        "train",
        "--task",
        "circle-3",
        "--method",
        "sili",
        "--interactions",
        12,
        "--seed",
        1,
        "--out",
        out,
        "--checkpoint-every",
        5,
        *FAST,
    )
    assert res.returncode == 0, res.stderr
    assert json.loads(res.stdout)["interactions"] == 12
    cfg = json.loads((out / "config.json").read_text())
    assert cfg["run"]["method"] == "sili" and cfg["run"]["seed"] == 1
    agent = cfg["run"]["agent"]
    assert agent["sili"]["beta"] == {"points": [[250, 0.0], [300, 0.5]]}  # SILI's default b
    assert agent["latent"] == "discrete"
    assert "torch" in cfg["versions"]
    assert cfg["versions"]["mujoco"].startswith("3.3.") and cfg["versions"]["mink"] == "0.0.5"
    assert cfg["versions"]["machine"].endswith("| 1 thread")  # the CPU the kernels ran on
    assert "scipy" in cfg["versions"]  # category matching, k-means
    revision = cfg["versions"].get("sili_robots_revision")  # the code, not only its version
    assert revision == code_revision()  # None: not run from a checkout git can read
    assert revision is None or re.fullmatch(r"[0-9a-f]{12}(\+[0-9a-f]{12})?", revision)
    df = pd.read_csv(out / "metrics.csv")
    assert list(df["interaction"]) == list(range(12))
    for col in (
        "task_reward",
        "stability_reward",
        "strategy_changed",
        "latent_category",
        "critic_loss",
        "latent_loss",
    ):
        assert col in df.columns
    assert df["critic_loss"].notna().sum() > 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["window"] == 12  # all of a run shorter than 100
    assert summary["final_task_reward"] == pytest.approx(df["task_reward"].mean())
    assert summary["final_stability"] == pytest.approx(1 - df["strategy_changed"][1:].mean())
    checkpoint = (out / "checkpoint.pt").read_bytes()
    ev = _sili("eval", out, "--interactions", 4)
    assert ev.returncode == 0, ev.stderr
    result = json.loads(ev.stdout)
    assert result["interactions"] == 4 and 0.0 <= result["fraction_strategy_unchanged"] <= 1.0
    assert result["mean_task_reward"] < 0
    # greedy, from the checkpointed game, learning nothing: the same numbers again
    own = {"run_dir": str(out), "trained_with": {}, "played_with": {}}  # Circle: none
    assert {**evaluate(out, 4), **own} == result
    assert (out / "checkpoint.pt").read_bytes() == checkpoint
    # the numbers of a greedy play of the same interactions, step by step
    _, env, agent, state = load_trained(out)
    play = AgentFeedback(env, agent, state["game"])
    obs, info = play.reset()
    rewards, changed = [], []
    for _ in range(4):
        changed.append(info["strategy_changed"])
        total = 0.0
        for _ in range(env.unwrapped.horizon):
            obs, reward, _, _, info = play.step(agent.act(obs, deterministic=True))
            total += reward
        rewards.append(total)
        obs, info = play.reset()
    play.close()
    assert result["mean_task_reward"] == pytest.approx(np.mean(rewards))
    # after the first, whose change the training's last interaction caused
    assert result["fraction_strategy_unchanged"] == pytest.approx(1 - np.mean(changed[1:]))
    assert result["trained_interactions"] == 12 and "unfinished" not in ev.stderr
    set_target(out, 20)  # as a run stopped short of its target
    note = _sili("eval", out, "--interactions", 1)
    assert note.returncode == 0
    assert "is unfinished: this evaluates its checkpoint at interaction 12 of 20" in note.stderr
    assert json.loads(note.stdout)["fraction_strategy_unchanged"] is None  # none after the first


def test_the_recorded_revision_is_the_commit_and_a_digest_of_code_edits_alone(tmp_path):
    root = Path(__file__).resolve().parents[1]
    if code_revision(root) is None:
        pytest.skip("not a checkout git can read")
    clone = tmp_path / "clone"
    subprocess.run(["git", "clone", "-q", str(root), str(clone)], check=True)
    head = subprocess.run(
        ["git", "-C", str(clone), "rev-parse", "HEAD"], capture_output=True, text=True, check=True
    ).stdout.strip()[:12]

    def revision(**git_env: str) -> str | None:
        code_revision.cache_clear()
        with pytest.MonkeyPatch.context() as patch:
            for key, value in git_env.items():
                patch.setenv(key, value)
            return code_revision(clone)

    package = clone / "sili_robots"
    assert revision() == head  # a commit, never a tag name
    (clone / "README.md").write_text("edited")  # not the package's code
    (package / ".verdict.py.swp").write_bytes(b"an editor's")  # nor an editor's file
    assert revision() == head
    (package / "verdict.py").write_text("HOLDS = 0.8\n")
    edited = revision()
    assert re.fullmatch(rf"{head}\+[0-9a-f]{{12}}", edited)
    # the same code, whatever git's settings for showing diffs: external, colour, prefixes
    for key, value in (("diff.external", "true"), ("color.diff", "always")):
        assert (
            revision(GIT_CONFIG_COUNT="1", GIT_CONFIG_KEY_0=key, GIT_CONFIG_VALUE_0=value) == edited
        )
    subprocess.run(["git", "-C", str(clone), "add", "sili_robots/verdict.py"], check=True)
    assert revision() == edited  # staged: the same
    (package / "verdict.py").write_text("HOLDS = 0.7\n")
    assert revision() not in (edited, head)  # another edit, another digest
    (package / "verdict.py").write_text("HOLDS = 0.8\n")
    (package / os.fsdecode(b"caf\xe9.py")).write_text("A = 1\n")  # a new module counts too
    assert revision() not in (edited, head)
    code_revision.cache_clear()


def test_a_run_of_your_own_task_records_its_code_and_one_of_a_script_s_class_goes_without():
    from sili_robots.build import make_run_config
    from sili_robots.examples import two_doors

    cfg = make_run_config("sili_robots.examples.two_doors:TwoDoorsEnv", "sili")
    digest = hashlib.sha256(Path(two_doors.__file__).read_bytes()).hexdigest()[:12]
    assert cfg.provenance()["code of sili_robots.examples.two_doors:TwoDoorsEnv"] == digest
    cfg.task = "__main__:TwoDoorsEnv"  # trained as an instance: nothing to import it by
    assert not [k for k in cfg.provenance() if k.startswith("code of ")]


def test_a_revision_unknown_on_one_side_is_no_continuation(tmp_path):
    args = ["train", "--task", "circle-3", "--method", "sac", "--interactions", "1", *FAST]
    run = tmp_path / "run"
    assert main([*args, "--out", str(run)]) == 0
    record = json.loads((run / "config.json").read_text())
    now = record["versions"].get("sili_robots_revision")
    record["versions"].pop("sili_robots_revision", None)  # an installed package wrote it
    (run / "config.json").write_text(json.dumps(record))
    record_continuation(run, read_config(run), 1)
    assert "continued" not in json.loads((run / "config.json").read_text())
    if now is None:
        return  # not run from a checkout: nothing to tell apart
    record["versions"]["sili_robots_revision"] = "0123456789ab"  # other code, alone
    (run / "config.json").write_text(json.dumps(record))
    record_continuation(run, read_config(run), 1)
    (continued,) = json.loads((run / "config.json").read_text())["continued"]
    assert continued["from_interaction"] == 1
    assert continued["versions"]["sili_robots_revision"] == now


def test_a_run_is_compared_with_the_software_it_last_ran_on(tmp_path):
    """Going on where its latest session ran adds no continuation; other software does."""
    args = ["train", "--task", "circle-3", "--method", "sac", "--interactions", "1", *FAST]
    run = tmp_path / "run"
    assert main([*args, "--out", str(run)]) == 0
    cfg = read_config(run)
    now = cfg.provenance()
    record = json.loads((run / "config.json").read_text())
    began, middle = ({**now, "torch": f"0.0.{i}"} for i in (1, 2))
    record["versions"] = began
    for sessions, noted in (((middle, now), [1, 2]), ((now, middle), [1, 2, 3])):
        record["continued"] = [
            {"from_interaction": i, "versions": v} for i, v in enumerate(sessions, start=1)
        ]
        (run / "config.json").write_text(json.dumps(record))
        record_continuation(run, cfg, 3)
        continued = json.loads((run / "config.json").read_text())["continued"]
        assert [c["from_interaction"] for c in continued] == noted


def test_the_first_interactions_are_random_and_learning_starts_after_them(tmp_path, monkeypatch):
    from sili_robots.agent import SILIAgent
    from sili_robots.build import make_run_config

    calls = {"act": 0, "random": 0}
    act, random_action = SILIAgent.act, SILIAgent.random_action

    def counted_act(self, *args, **kwargs):
        calls["act"] += 1
        return act(self, *args, **kwargs)

    def counted_random(self, *args, **kwargs):
        calls["random"] += 1
        return random_action(self, *args, **kwargs)

    monkeypatch.setattr(SILIAgent, "act", counted_act)
    monkeypatch.setattr(SILIAgent, "random_action", counted_random)
    settings = {**FAST_AGENT, "random_interactions": 3}
    cfg = make_run_config("circle-3", "sac", 0, 5, settings=settings)
    training.train(cfg, tmp_path / "run", progress=False)
    assert calls == {"random": 3 * 50, "act": 2 * 50}  # H = 50
    df = pd.read_csv(tmp_path / "run" / "metrics.csv")
    # SAC's first updates come after the last random interaction, on what it gathered
    assert df["critic_loss"].isna().tolist() == [True, True, False, False, False]


def test_the_summary_is_the_last_window_of_the_metrics(tmp_path):
    rows = 150
    df = pd.DataFrame(
        {
            "interaction": range(rows),
            "task_reward": np.arange(rows, dtype=float),
            "stability_reward": 0.0,
            "strategy_changed": np.arange(rows) < 75,  # changed in the first half only
            "latent_category": -1,
            "wall_time": np.linspace(0, 9, rows),
        }
    )
    df.to_csv(tmp_path / "metrics.csv", index=False)
    summary = write_summary(tmp_path)
    assert summary == json.loads((tmp_path / "summary.json").read_text())
    assert summary["interactions"] == rows and summary["window"] == 100
    assert summary["final_task_reward"] == pytest.approx(np.arange(50, 150).mean())
    assert summary["final_stability"] == pytest.approx(0.75)
    assert summary["wall_time_s"] == 9.0
    df.head(0).to_csv(tmp_path / "metrics.csv", index=False)  # no row: means of nothing

    def strict(constant: str) -> None:
        raise ValueError(f"{constant} is not JSON")

    write_summary(tmp_path)
    text = (tmp_path / "summary.json").read_text()
    assert json.loads(text, parse_constant=strict)["final_task_reward"] is None


@pytest.mark.parametrize("method", ["lili", "stable", "sac", "oracle", "smirl"])
def test_every_method_trains(tmp_path, method):
    out = tmp_path / method
    res = _sili(
        "train", "--task", "circle-3", "--method", method, "--interactions", 5, "--out", out, *FAST
    )
    assert res.returncode == 0, res.stderr
    df = pd.read_csv(out / "metrics.csv")
    assert len(df) == 5
    # methods without a latent model report no latent category
    assert (df["latent_category"] == -1).all() == (method in ("sac", "oracle", "smirl"))


def test_entropy_discount_and_lr_schedules_are_saved_with_the_run(tmp_path):
    """Any method takes them (Oracle too, so a late change can be compared fairly)."""
    out = tmp_path / "oracle"
    res = _sili(
        "train", "--task", "circle-3", "--method", "oracle", "--interactions", 3, "--out", out,
        "--target-entropy-schedule", "0:-2,2:-4", "--discount-schedule", "1:0.99,2:0.998",
        "--lr-schedule", "1:3e-4,2:3e-5", *FAST,
    )  # fmt: skip
    assert res.returncode == 0, res.stderr
    agent = json.loads((out / "config.json").read_text())["run"]["agent"]
    assert agent["sac"]["target_entropy"] == {"points": [[0, -2.0], [2, -4.0]]}
    assert agent["sac"]["gamma"] == {"points": [[1, 0.99], [2, 0.998]]}
    assert agent["sac"]["lr"] == {"points": [[1, 3e-4], [2, 3e-5]]}


def test_a_setting_given_again_under_any_of_its_names_keeps_the_last_value():
    from sili_robots.build import make_run_config
    from sili_robots.commands.common import parse_settings

    for items, last in (
        (["sac.lr=0.001", "lr=0.002", "sac.lr=0.003"], 0.003),
        (["lr=0.002", "sac.lr=0.003", "lr=0.004"], 0.004),
    ):
        cfg = make_run_config("circle-3", "sili", 0, 1, settings=parse_settings(items))
        assert cfg.agent.sac.lr == last, items


@pytest.mark.parametrize("latent", ["continuous", "partial", "true"])
def test_every_latent_kind_trains(tmp_path, latent):
    out = tmp_path / latent
    res = _sili(
        "train",
        "--task",
        "speaker-listener",
        "--latent",
        latent,
        "--interactions",
        5,
        "--out",
        out,
        *FAST,
    )
    assert res.returncode == 0, res.stderr
    cfg, env, agent, _ = load_trained(out)
    assert cfg.agent.latent == latent
    base = env.unwrapped.observation_space.shape[0]
    assert agent.obs_dim == base + (latent == "partial")  # the "strategy changed" flag
    assert agent.zdim == (env.unwrapped.strategy_dim if latent == "true" else cfg.agent.model.dim)
    assert (agent.model is not None) == (latent == "continuous")


@pytest.mark.parametrize(
    "args,message",
    [
        (["--task", "circle-9"], "unknown task 'circle-9'"),
        (["--task", "circle-3", "--method", "ppo"], "invalid choice: 'ppo'"),
        (["--task", "circle-3", "--latent", "none"], "invalid choice: 'none'"),
        (["--task", "circle-3", "--beta", "1.5"], "outside the allowed range [0, 1]"),
        (["--task", "circle-3", "--interactions", "0"], "need an integer >= 1"),
        (["--task", "circle-3", "--set", "gamma=2"], "sac.gamma must be in [1e-09, 1], got 2"),
        (["--task", "circle-3", "--set", "sac.updates_per_step=Infinity"], "must be a finite"),
        (
            ["--task", "circle-3", "--set", "sac.updates_per_step=1e17"],
            "updates_per_step must be in [0, 10000], got 1e+17",
        ),
        (["--task", "circle-3", "--set", "sac.target_entropy=-Infinity"], "must be a finite"),
        (["--task", "circle-3", "--set", "hidden=1e300"], "hidden must be at most 2147483647"),
        (
            ["--task", "circle-3", "--set", "sili.scale=1e39"],
            "sili.scale must be less than 3.4028235677973366e+38 in size (the networks compute in "
            "float32, where 1e+39 is infinite)",
        ),
        (["--task", "circle-3", "--set", "sac.target_entropy=-1e39"], "where -1e+39 is infinite"),
        (["--task", "circle-3", "--set", "hidden=-1e39"], "hidden must be >= 1, got"),
        (
            ["--task", "circle-3", "--set", 'model.usage_bonus={"points": [[0, 1e39]]}'],
            "schedule of model.usage_bonus: a value must be less than 3.4028235677973366e+38",
        ),
        (["--task", "circle-3", "--set", "sac.lr.x=1"], "unknown setting 'sac.lr.x'"),
        (["--task", "circle-3", "--set", 'sac.lr={"start": 0}'], "sac.lr: a schedule is"),
        (["--task", "circle-3", "--set", 'sac.lr={"points": [[0, "a"]]}'], "a schedule is"),
        (
            ["--task", "circle-3", "--set", 'sac.lr={"points": [[2.7, 1e-3]]}'],
            "whole numbers, got 2.7",
        ),
        (
            ["--task", "circle-3", "--set", 'sac.lr={"points": [[Infinity, 1e-3]]}'],
            "sac.lr: a schedule's interactions are whole numbers, got inf",  # not OverflowError
        ),
        (["--task", "circle-3", "--set", 'tau={"start": 0, "end": 1, "length": NaN}'], "got nan"),
        (["--task", "circle-3", "--method", "lili", "--beta", "0.3"], "does not apply to method"),
        (["--task", "circle-3", "--beta-anneal", "2", "0", "10"], "outside the allowed range"),
        (["--task", "circle-3", "--beta-anneal", "0", "0.5"], "START END LENGTH [DELAY]"),
        (["--task", "circle-3", "--beta-anneal", "0", "0.5", "9", "-1"], "need an integer >= 0"),
        (
            [
                "--task",
                "circle-3",
                "--beta-anneal",
                "0",
                "0.5",
                "9",
                "--beta-anneal",
                "0",
                "1",
                "9",
            ],
            "--beta-anneal given 2 times; give it once",  # never only the last segment kept
        ),
        (["--task", "circle-3", "--beta-schedule", "0:0,300:1.5"], "outside the allowed range"),
        (["--task", "circle-3", "--beta-schedule", "300:0.5,250:0"], "must increase"),
        (["--task", "circle-3", "--beta-schedule", "300"], "'300' is not INTERACTION:VALUE"),
        (["--task", "circle-3", "--set", "sac.lr=2200:3e-4,xx"], "'xx' is not INTERACTION:VALUE"),
        (
            ["--task", "circle-3", "--target-entropy-schedule", "1500:-2,1600:x"],
            "--target-entropy-schedule '1500:-2,1600:x': 'x' is not a number",
        ),
        (
            ["--task", "circle-3", "--target-entropy-schedule", "0:inf"],
            "'inf' is not a finite number",
        ),
        (
            ["--task", "circle-3", "--discount-schedule", "0:0.99,1600:1.2"],
            "--discount-schedule '0:0.99,1600:1.2': 1.2 is outside the allowed range [0, 1]",
        ),
        (
            ["--task", "circle-3", "--discount-schedule", "0:0.99", "--set", "gamma=0.9"],
            "give one of --set gamma and --discount-schedule",
        ),
        (
            ["--task", "circle-3", "--lr-schedule", "0:3e-4,2200:-1"],
            "--lr-schedule '0:3e-4,2200:-1': -1.0 is outside the allowed range [0, 1]",
        ),
        (
            ["--task", "circle-3", "--lr-schedule", "0:3e-4", "--set", "lr=1e-3"],
            "give one of --set lr and --lr-schedule",
        ),
        (
            [
                "--task",
                "circle-3",
                "--target-entropy-schedule",
                "0:-2",
                "--set",
                "target_entropy=-3",
            ],
            "give one of --set target_entropy and --target-entropy-schedule, not both",
        ),
        (
            ["--task", "circle-3", "--method", "lili", "--beta-schedule", "0:0.5"],
            "--beta-schedule does not apply to method 'lili'",
        ),
        (
            ["--task", "circle-3", "--beta-anneal", "0", "0.5", "9", "--beta-schedule", "0:0"],
            "not both",
        ),
        (
            ["--task", "circle-3", "--beta", "0.3", "--beta-schedule", "0:0"],
            "give one of --beta and --beta-schedule, not both",
        ),
        (
            ["--task", "circle-3", "--set", "beta=0.3", "--beta-anneal", "0", "0.5", "9"],
            "give one of --set beta and --beta-anneal, not both",
        ),
        (["--resume", "/nonexistent"], "/nonexistent does not exist; give a run directory"),
        (
            ["--task", "circle-3", "--controller", "osc"],
            "task 'circle-3' takes no argument controller (--controller, --env-kwarg); its "
            "arguments: horizon, outside_margin, near_moves (variant is fixed by the name)",
        ),
        (
            ["--task", "sawyer-reach", "--controller", "mink,osc"],
            "--controller mink,osc: a run trains with one controller; a run with each: sili "
            "sweep --tasks sawyer-reach --methods sili --controller mink,osc --out SWEEP_DIR",
        ),
    ],
)
def test_bad_input_exits_2_without_traceback(tmp_path, args, message):
    extra = [] if "--resume" in args else ["--out", str(tmp_path / "x")]
    if not {"--resume", "--interactions"} & set(args):  # a refusal that broke trains briefly
        extra += ["--interactions", "1", "--no-progress"]
    res = _sili("train", *args, *extra)
    assert res.returncode == 2, res.stderr
    assert message in res.stderr
    assert "Traceback" not in res.stderr


def test_a_schedule_knot_at_numpy_s_infinity_is_named_too():
    from sili_robots.build import make_run_config

    for knot in (np.float32("inf"), np.float64("nan")):
        points = {"points": [[0, 1e-3], [knot, 1e-4]]}
        with pytest.raises(ConfigError, match="a schedule's interactions are whole numbers, got"):
            make_run_config("circle-3", "sac", settings={"sac.lr": points})


def test_float32s_largest_number_is_a_setting_and_one_that_rounds_past_it_is_not():
    from sili_robots.agent.config import FLOAT32_OVERFLOW
    from sili_robots.build import make_run_config

    printed = 3.4028235e38  # float32's largest as numpy prints it: a hair above, rounds to it
    assert np.float32(printed) == np.finfo(np.float32).max
    cfg = make_run_config("circle-3", "sili", 0, 1, settings={"sili.scale": printed})
    assert cfg.agent.sili.scale == printed
    assert np.isfinite(np.float32(np.nextafter(FLOAT32_OVERFLOW, 0.0)))
    with pytest.raises(ConfigError, match=r"where 3.4028235677973366e\+38 is infinite"):
        make_run_config("circle-3", "sili", 0, 1, settings={"sili.scale": FLOAT32_OVERFLOW})


def test_eval_of_a_non_run_exits_2(tmp_path):
    res = _sili("eval", tmp_path)
    assert res.returncode == 2 and "is not a run directory" in res.stderr
    (tmp_path / "config.json").write_text("{}")  # a run's file, given for its folder
    res = _sili("eval", tmp_path / "config.json")
    said = f"{tmp_path / 'config.json'} is a file, not a run directory: give {tmp_path}\n"
    assert res.returncode == 2 and res.stderr.endswith(said), res.stderr
    sweep = tmp_path / "sweep"  # its runs are one level down
    for name in ("c", "b", "a"):
        (sweep / "runs" / name).mkdir(parents=True)
        (sweep / "runs" / name / "config.json").write_text("{}")
    res = _sili("eval", sweep)  # a collection: none kept its checkpoint
    said = "it holds runs without their checkpoint.pt (a collection): give the run in the sweep"
    assert res.returncode == 2 and said in res.stderr, res.stderr
    for name in ("c", "b"):
        (sweep / "runs" / name / "checkpoint.pt").write_bytes(b"")
    res = _sili("eval", sweep)  # the first that can be played, not the first by name
    said = f"it is a sweep: give one of its runs, e.g. {sweep / 'runs' / 'b'}\n"
    assert res.returncode == 2 and res.stderr.endswith(said), res.stderr


def test_a_damaged_checkpoint_or_config_exits_2_naming_the_file(tmp_path):
    run = tmp_path / "run"
    assert (
        _sili("train", "--task", "circle-3", "--interactions", 2, *FAST, "--out", run).returncode
        == 0
    )
    ckpt = run / "checkpoint.pt"
    whole = ckpt.read_bytes()
    for cut in (5000, 60000):  # torch's zip reader raised OSError (EINVAL): a traceback
        ckpt.write_bytes(whole[:cut])
        res = _sili("eval", run, "--interactions", 1)
        assert res.returncode == 2 and f"{ckpt} is damaged" in res.stderr, res.stderr
    ckpt.unlink()
    ckpt.mkdir()  # was "has no checkpoint yet (no checkpoint.pt); train it first"
    res = _sili("eval", run, "--interactions", 1)
    assert res.returncode == 2 and f"{ckpt} is not a checkpoint file (a folder?)" in res.stderr
    ckpt.rmdir()
    ckpt.write_bytes(whole[:1000])  # cut short, as by a full disk
    res = _sili("train", "--resume", run, "--interactions", 3)
    assert res.returncode == 2 and f"{ckpt} is damaged" in res.stderr, res.stderr
    # refused before the run changed: still a finished run of 2
    assert json.loads((run / "config.json").read_text())["run"]["interactions"] == 2
    assert run_state(run) == "done"
    res = _sili("eval", run, "--interactions", 1)
    assert res.returncode == 2 and "can be neither resumed nor played from it" in res.stderr
    (run / "config.json").write_text("{not json")
    res = _sili("eval", run, "--interactions", 1)
    assert res.returncode == 2 and f"{run / 'config.json'} is damaged" in res.stderr


def test_a_checkpoint_of_another_run_exits_2_and_leaves_the_run_as_it_was(tmp_path, capsys):
    run, other = tmp_path / "run", tmp_path / "other"
    args = ["train", "--task", "circle-3", "--interactions", "2", *FAST]
    assert main([*args, "--out", str(run)]) == 0
    assert main([*args, "--method", "sac", "--out", str(other)]) == 0
    shutil.copy(other / "checkpoint.pt", run / "checkpoint.pt")  # a SAC agent's networks
    capsys.readouterr()
    assert main(["train", "--resume", str(run), "--interactions", "3", "--no-progress"]) == 2
    assert "checkpoint.pt is a checkpoint of method 'sac', not of the run in" in (
        capsys.readouterr().err
    )
    sac = torch.load(other / "checkpoint.pt", weights_only=False)
    del sac["method"], sac["seed"], sac["run"]  # as earlier versions': its networks are told
    torch.save(sac, run / "checkpoint.pt")
    said = f"{run / 'checkpoint.pt'} does not fit the agent {run / 'config.json'} describes"
    assert main(["train", "--resume", str(run), "--interactions", "3", "--no-progress"]) == 2
    assert said in capsys.readouterr().err
    # refused before the run changed: still a finished run of 2
    assert json.loads((run / "config.json").read_text())["run"]["interactions"] == 2
    assert run_state(run) == "done"
    own = ["--env-kwarg", "horizon=50"]  # the run's own argument, given: still the run's task
    for command in (["eval", str(run), "--interactions", "1"], ["preview", "circle-3"]):
        if command[0] == "preview":
            command += ["--checkpoint", str(run), "--out", str(tmp_path / "p.html")]
        for given in ([], own):
            assert main(command + given) == 2
            assert said in capsys.readouterr().err
    with pytest.raises(ConfigError, match="does not fit the agent"):
        SILI.load(run)
    # another task's agent of the same sizes: refused by the task its checkpoint names
    circle8 = tmp_path / "circle8"
    assert (
        main(["train", "--task", "circle-8", "--interactions", "2", *FAST, "--out", str(circle8)])
        == 0
    )
    shutil.copy(circle8 / "checkpoint.pt", run / "checkpoint.pt")
    capsys.readouterr()
    assert main(["train", "--resume", str(run), "--interactions", "3", "--no-progress"]) == 2
    said = f"checkpoint.pt is a checkpoint of task 'sili/Circle8-v1', not of the run in {run} ("
    assert said in capsys.readouterr().err
    assert json.loads((run / "config.json").read_text())["run"]["interactions"] == 2
    assert run_state(run) == "done"
    # another seed's agent of the same task and sizes (the networks fit): refused by its seed,
    # also from a longer run (named as a copy, not as a damaged count)
    seed1 = tmp_path / "seed1"
    assert main([*args, "--seed", "1", "--interactions", "3", "--out", str(seed1)]) == 0
    shutil.copy(seed1 / "checkpoint.pt", run / "checkpoint.pt")
    capsys.readouterr()
    for command in (["eval", str(run)], ["train", "--resume", str(run), "--no-progress"]):
        assert main(command) == 2
        assert "checkpoint.pt is a checkpoint of seed 1, not of the run in" in (
            capsys.readouterr().err
        )


def test_a_checkpoint_of_a_run_of_other_settings_is_refused_by_them(tmp_path, capsys):
    """Same task, method and seed, networks of the same sizes: a checkpoint copied from a run of
    another learning rate (or under a config.json edited since) went on as if it were this run's;
    a longer budget and another machine's settings are the same run."""
    run, other = tmp_path / "run", tmp_path / "other"
    args = ["train", "--task", "circle-3", "--interactions", "2", *FAST, "--no-progress"]
    assert main([*args, "--out", str(run)]) == 0
    assert main([*args, "--set", "sac.lr=0.001", "--out", str(other)]) == 0
    shutil.copy(other / "checkpoint.pt", run / "checkpoint.pt")
    rows = (run / "metrics.csv").read_text()
    capsys.readouterr()
    for command in (["eval", str(run)], ["train", "--resume", str(run), "--interactions", "3"]):
        assert main(command) == 2
        err = capsys.readouterr().err
        assert (
            "checkpoint.pt is a checkpoint of a run with other settings (agent.sac.lr 0.001 " in err
        )
        assert "was it copied from another run, or the config edited?" in err
    assert (run / "metrics.csv").read_text() == rows and run_state(run) == "done"
    margin = tmp_path / "margin"  # other task arguments: another run too
    assert main([*args, "--env-kwarg", "outside_margin=0.2", "--out", str(margin)]) == 0
    shutil.copy(margin / "checkpoint.pt", run / "checkpoint.pt")
    capsys.readouterr()
    assert main(["train", "--resume", str(run), "--interactions", "3"]) == 2
    assert "(env_kwargs.outside_margin 0.2 there, None here)" in capsys.readouterr().err
    record = json.loads((other / "config.json").read_text())
    record["run"]["threads"] = 2  # another machine's setting: the same run, extended
    (other / "config.json").write_text(json.dumps(record))
    assert main(["train", "--resume", str(other), "--interactions", "3", "--no-progress"]) == 0
    assert main(["eval", str(other), "--interactions", "1"]) == 0


def test_a_checkpoint_with_a_bad_count_is_refused_before_the_run_changes(tmp_path, capsys):
    """An interaction of -5 was resumed from, writing over the run's rows; "abc" was a
    traceback; 169 in a run of 2 was evaluated without a word; a wall time of -5 s went on."""
    run = tmp_path / "run"
    args = ["train", "--task", "circle-3", "--interactions", "2", *FAST, "--out", str(run)]
    assert main(args) == 0
    rows = (run / "metrics.csv").read_text()
    good = torch.load(run / "checkpoint.pt", weights_only=False)
    for key, bad in [
        ("interaction", -5),
        ("interaction", "abc"),
        ("interaction", 169),
        ("interaction", True),
        ("wall_time", "abc"),
        ("wall_time", float("nan")),
        ("wall_time", -5.0),
    ]:
        torch.save({**good, key: bad}, run / "checkpoint.pt")
        for command in (["eval", str(run)], ["train", "--resume", str(run), "--interactions", "5"]):
            assert main([*command, "--no-progress"] if command[0] == "train" else command) == 2
            assert (
                f"checkpoint.pt is damaged (its {key} is {bad!r}, not a" in capsys.readouterr().err
            )
        assert (run / "metrics.csv").read_text() == rows
        assert json.loads((run / "config.json").read_text())["run"]["interactions"] == 2


def test_a_recorded_task_argument_the_task_refuses_names_the_run_s_config(tmp_path, capsys):
    run = tmp_path / "run"
    args = ["train", "--task", "circle-3", "--interactions", "2", *FAST, "--out", str(run)]
    assert main(args) == 0
    record = json.loads((run / "config.json").read_text())
    record["run"]["env_kwargs"] = {"horizon": 0}  # edited by hand: not the checkpoint's run
    (run / "config.json").write_text(json.dumps(record))
    assert main(["eval", str(run)]) == 2
    assert "checkpoint of a run with other settings (env_kwargs.horizon None there, 0 here)" in (
        capsys.readouterr().err
    )
    state = torch.load(run / "checkpoint.pt", weights_only=False)
    del state["run"]  # as checkpoints of earlier versions: the task refuses the arguments
    torch.save(state, run / "checkpoint.pt")
    said = (
        f"the run in {run} records task sili/Circle3-v1 with arguments {{'horizon': 0}} "
        f"({run / 'config.json'}), which does not build here: horizon must be an integer in"
    )
    for command in (["eval", str(run)], ["train", "--resume", str(run), "--no-progress"]):
        assert main(command) == 2
        assert said in capsys.readouterr().err
    with pytest.raises(ConfigError, match=re.escape(said)):
        SILI.load(run)


def test_training_that_diverges_exits_2_naming_the_losses(tmp_path, capsys, monkeypatch):
    from sili_robots.agent import config

    monkeypatch.setattr(config, "FLOAT32_OVERFLOW", float("inf"))  # let 1e300 through: NaN losses
    args = ["train", "--task", "circle-3", "--interactions", "2", *FAST]
    huge = ["--set", "sac.target_entropy=1e300", "--set", "sac.random_interactions=0"]
    assert main([*args, *huge, "--out", str(tmp_path / "huge")]) == 2
    err = capsys.readouterr().err
    assert "training diverged after interaction 0 (critic_loss nan" in err
    assert "action must be finite" not in err
    # a latent model given no updates has a NaN loss by design, not a divergence
    idle = ["--set", "model.updates_per_interaction=0"]
    assert main([*args, *idle, "--out", str(tmp_path / "idle")]) == 0
    assert pd.read_csv(tmp_path / "idle" / "metrics.csv")["latent_loss"].isna().all()


def test_resume_after_kill_reproduces_the_uninterrupted_run(tmp_path):
    args = [
        "--task",
        "circle-3",
        "--method",
        "sili",
        "--interactions",
        30,
        "--seed",
        3,
        "--checkpoint-every",
        5,
        *FAST,
    ]
    full = tmp_path / "full"
    assert _sili("train", *args, "--out", full).returncode == 0
    killed = tmp_path / "killed"
    proc = subprocess.Popen(
        [sys.executable, "-m", "sili_robots.cli", "train", *map(str, args), "--out", str(killed)],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    deadline = time.time() + 120
    metrics = killed / "metrics.csv"
    while time.time() < deadline:
        if metrics.exists() and len(metrics.read_text().splitlines()) >= 1 + 13:
            break
        time.sleep(0.05)
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    rows_at_kill = len(pd.read_csv(metrics))
    assert 13 <= rows_at_kill < 30
    res = _sili("train", "--resume", killed, "--no-progress")
    assert res.returncode == 0, res.stderr
    a = pd.read_csv(full / "metrics.csv").drop(columns="wall_time")
    b = pd.read_csv(killed / "metrics.csv").drop(columns="wall_time")
    assert len(b) == 30
    pd.testing.assert_frame_equal(a, b)


def _default_sigint() -> None:
    signal.signal(signal.SIGINT, signal.SIG_DFL)  # a terminal's, not a background job's SIG_IGN


@pytest.mark.parametrize(
    ("sig", "code", "said"),
    [(signal.SIGINT, 130, "interrupted"), (signal.SIGTERM, 143, "stopped by SIGTERM")],
)
def test_a_stopped_run_checkpoints_its_last_interaction_first(tmp_path, sig, code, said):
    """Ctrl-C or SIGTERM mid-interaction: the run logs and checkpoints that interaction, then
    stops as the signal says; nothing since the last regular checkpoint is lost."""
    args = ["--task", "circle-3", "--method", "sili", "--interactions", 80, "--seed", 1]
    args += ["--checkpoint-every", 1000, *FAST]  # no regular checkpoint before the end
    run = tmp_path / "stopped"
    proc = subprocess.Popen(
        [sys.executable, "-m", "sili_robots.cli", "train", *map(str, args), "--out", str(run)],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
        preexec_fn=_default_sigint,
    )
    deadline = time.time() + 120
    while time.time() < deadline and not (
        (run / "metrics.csv").exists() and len((run / "metrics.csv").read_text().splitlines()) > 5
    ):
        time.sleep(0.02)
    proc.send_signal(sig)
    stderr = proc.communicate(timeout=120)[1]
    assert proc.returncode == code and said in stderr and "Traceback" not in stderr, stderr
    assert f"continue the run with: sili train --resume {run}" in stderr
    rows = len(pd.read_csv(run / "metrics.csv"))
    assert 5 <= rows < 80 and load_checkpoint(run)["interaction"] == rows  # none lost
    assert _sili("train", "--resume", run, "--no-progress").returncode == 0
    again = _sili("train", "--resume", run, "--no-progress")  # finished: says so, changes nothing
    assert again.returncode == 0 and len(pd.read_csv(run / "metrics.csv")) == 80
    assert f"{run} has already trained all 80 of its interactions; --interactions N" in again.stderr
    full = tmp_path / "full"
    assert _sili("train", *args, "--out", full).returncode == 0
    a = pd.read_csv(full / "metrics.csv").drop(columns="wall_time")
    pd.testing.assert_frame_equal(a, pd.read_csv(run / "metrics.csv").drop(columns="wall_time"))


def test_a_stop_in_the_last_interaction_leaves_the_run_finished(tmp_path, monkeypatch, capsys):
    """Everything is trained and saved when the stop acts: the run is done (its summary
    written), the command still stops as the signal says, and says the run finished."""
    played = []
    play = training.play_interaction

    def last_is_stopped(*args, **kwargs):
        played.append(1)
        if len(played) == 3:
            os.kill(os.getpid(), signal.SIGINT)  # held until the interaction is saved
        return play(*args, **kwargs)

    monkeypatch.setattr(training, "play_interaction", last_is_stopped)
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    run = tmp_path / "run"
    try:
        args = ["train", "--task", "circle-3", "--method", "sac", "--interactions", "3", *FAST]
        assert main([*args, "--out", str(run)]) == 130
    finally:
        signal.signal(signal.SIGINT, previous)
    err = capsys.readouterr().err
    assert f"the run finished all its interactions: {run}" in err and "--resume" not in err
    assert run_state(run) == "done"
    assert json.loads((run / "summary.json").read_text())["interactions"] == 3


def test_existing_run_is_not_overwritten_silently(tmp_path):
    out = tmp_path / "run"
    assert (
        _sili("train", "--task", "circle-3", "--interactions", 2, "--out", out, *FAST).returncode
        == 0
    )
    res = _sili("train", "--task", "circle-3", "--interactions", 2, "--out", out, *FAST)
    assert res.returncode == 2 and "--resume" in res.stderr
    assert Path(out / "config.json").exists()


def test_extending_a_finished_run_reproduces_the_longer_run(tmp_path):
    args = ["--task", "circle-3", "--method", "sili", "--seed", 2, "--checkpoint-every", 4, *FAST]
    longer, extended = tmp_path / "longer", tmp_path / "extended"
    assert _sili("train", *args, "--interactions", 12, "--out", longer).returncode == 0
    assert _sili("train", *args, "--interactions", 8, "--out", extended).returncode == 0
    res = _sili("train", "--resume", extended, "--interactions", 12, "--no-progress")
    assert res.returncode == 0, res.stderr
    assert json.loads((extended / "config.json").read_text())["run"]["interactions"] == 12
    a = pd.read_csv(longer / "metrics.csv").drop(columns="wall_time")
    b = pd.read_csv(extended / "metrics.csv").drop(columns="wall_time")
    assert len(b) == 12
    pd.testing.assert_frame_equal(a, b)
    res = _sili("train", "--resume", extended, "--interactions", 5, "--no-progress")
    assert res.returncode == 2 and "would shorten" in res.stderr and ">= 12" in res.stderr
    assert "Traceback" not in res.stderr
    # what the run records is not changed on resume: options that would are refused by name
    res = _sili("train", "--resume", extended, "--interactions", 14, "--set", "sac.lr=1e-3")
    assert res.returncode == 2 and "not --set" in res.stderr
    res = _sili("train", "--resume", extended, "--method", "lili", "--no-progress")
    assert res.returncode == 2 and "not --method" in res.stderr
    res = _sili("train", "--resume", extended, "--seed", 0)  # typed, even at its default
    assert res.returncode == 2 and "not --seed" in res.stderr
    assert json.loads((extended / "config.json").read_text())["run"]["interactions"] == 12


def test_a_continuous_filter_started_late_leaves_the_run_unchanged_before_it(tmp_path):
    args = ["--task", "circle-3", "--latent", "continuous", "--seed", 2, *FAST]
    args += ["--checkpoint-every", 8, "--interactions", 24]
    plain, filtered = tmp_path / "plain", tmp_path / "filtered"
    assert _sili("train", *args, "--out", plain).returncode == 0
    filter_args = ["--set", "latent_filter=0.05", "--set", "latent_filter_start=16"]
    assert _sili("train", *args, *filter_args, "--out", filtered).returncode == 0
    a = pd.read_csv(plain / "metrics.csv").drop(columns="wall_time")
    b = pd.read_csv(filtered / "metrics.csv").drop(columns="wall_time")
    # the filter starts at the refresh after interaction 19 (20 stored): row 19 logs the first
    # updates on its latents, and every row before it is the unfiltered run's
    pd.testing.assert_frame_equal(a.iloc[:19], b.iloc[:19])
    assert not a.iloc[19:].equals(b.iloc[19:])
    assert (b["filter_step"].iloc[:20] == -1).all()  # played before the filter ran
    assert b["filter_step"].between(-1, 50).all()

    _, env, agent, _ = load_trained(filtered)
    env.close()
    lf = agent.addon(LatentFilter)
    assert lf.scale is not None and len(lf.candidates) >= 2
    assert len(lf.ZF) == 24
    # candidates are latents the encoder produced; every step acted on z^j or one of them
    assert all((agent.Z[1:] == c).all(-1).any() for c in lf.candidates)
    n_candidates = len(lf.candidates)
    assert lf.ZF.min() >= -1 and lf.ZF.max() < n_candidates
    np.testing.assert_array_equal(lf.ZF[:, 0], -1)  # no evidence yet: the encoder's z^j
    res = _sili("eval", filtered, "--interactions", 2)  # greedy, the filter running step by step
    assert res.returncode == 0 and "mean_task_reward" in res.stdout, res.stderr


def test_resuming_a_run_killed_before_its_first_checkpoint_says_it_starts_again(tmp_path, capsys):
    """Its logged interactions were never saved: they are trained and written anew, said so
    (a run with a checkpoint goes on from it without the note)."""
    run = tmp_path / "run"
    args = ["train", "--task", "circle-3", "--method", "sac", *FAST_ARGS, "--no-progress"]
    assert main([*args, "--interactions", "3", "--out", str(run)]) == 0
    (run / "checkpoint.pt").unlink()  # as if killed before it: neither checkpoint nor summary
    (run / "summary.json").unlink()
    capsys.readouterr()
    assert main(["train", "--resume", str(run), "--interactions", "4", "--no-progress"]) == 0
    err = capsys.readouterr().err
    assert f"note: {run} was stopped before its first checkpoint: its 3 logged interactions" in err
    assert "are discarded and it trains again from its first (no checkpoint holds them)" in err
    assert len((run / "metrics.csv").read_text().splitlines()) == 1 + 4
    assert main(["train", "--resume", str(run), "--interactions", "5", "--no-progress"]) == 0
    assert "first checkpoint" not in capsys.readouterr().err


def test_a_resumed_runs_progress_line_reads_as_an_uninterrupted_runs(tmp_path, monkeypatch):
    """Its window of the last 100 interactions holds those before the resume too."""
    from sili_robots.progress import TrainingProgress

    lines: list[tuple[float, float]] = []
    monkeypatch.setattr(TrainingProgress, "advance", lambda _, r, s: lines.append((r, s)))
    args = ["train", "--task", "circle-3", "--method", "sac", *FAST_ARGS, "--no-progress"]
    assert main([*args, "--interactions", "8", "--out", str(tmp_path / "whole")]) == 0
    whole = lines[:]
    assert main([*args, "--interactions", "4", "--out", str(tmp_path / "cut")]) == 0
    lines.clear()
    assert main(["train", "--resume", str(tmp_path / "cut"), "--interactions", "8"]) == 0
    assert len(lines) == 4
    np.testing.assert_allclose(lines, whole[4:])


def test_a_filtered_run_records_what_it_acted_on_and_resumes_exactly(tmp_path):
    args = ["--task", "circle-3", "--seed", 1, "--checkpoint-every", 8, *FAST]
    args += ["--set", "latent_filter=0.1"]
    longer, extended = tmp_path / "longer", tmp_path / "extended"
    assert _sili("train", *args, "--interactions", 24, "--out", longer).returncode == 0
    assert _sili("train", *args, "--interactions", 16, "--out", extended).returncode == 0
    res = _sili("train", "--resume", extended, "--interactions", 24, "--no-progress")
    assert res.returncode == 0, res.stderr
    a = pd.read_csv(longer / "metrics.csv").drop(columns="wall_time")
    pd.testing.assert_frame_equal(
        a, pd.read_csv(extended / "metrics.csv").drop(columns="wall_time")
    )

    _, env, agent, _ = load_trained(longer)
    env.close()
    lf = agent.addon(LatentFilter)
    assert lf.scale is not None and len(lf.ZF) == 24
    # interactions 20-23 came after the last refresh: their rows are what the policy acted on,
    # step by step, and the same model replaying them gives the same categories
    np.testing.assert_array_equal(lf.ZF[20:], lf._rows(np.arange(20, 24)))
    np.testing.assert_array_equal(lf.ZF[20:, 0], agent.Z[20:24].argmax(-1))  # the prior
    assert (lf.ZF >= 0).all()  # every row recomputed once the filter runs
    res = _sili("eval", longer, "--interactions", 2)  # greedy, the filter running step by step
    assert res.returncode == 0 and "mean_task_reward" in res.stdout, res.stderr


def test_threads_are_recorded_and_used(tmp_path):
    import torch

    out = tmp_path / "run"
    try:
        res = _sili(
            "train",
            "--task",
            "circle-3",
            "--method",
            "sac",
            "--interactions",
            4,
            "--threads",
            2,
            "--out",
            out,
            *FAST,
        )
        assert res.returncode == 0, res.stderr
        assert torch.get_num_threads() == 2  # the run's arithmetic ran on two threads
        cfg = json.loads((out / "config.json").read_text())
        assert cfg["run"]["threads"] == 2 and cfg["versions"]["machine"].endswith("| 2 threads")
        assert _sili("train", "--task", "circle-3", "--threads", 0, "--out", out).returncode == 2
    finally:
        torch.set_num_threads(1)


def test_a_two_thread_run_is_reproducible(tmp_path):
    """2 x 256 networks and the latent model's 1,600-row batches are large enough for torch to
    split products and sums over both threads; the seeded run still comes out the same."""
    import torch

    fast = ["--set", "updates_per_step=0.1", "--set", "random_interactions=3"]
    fast += ["--set", "latent_updates_per_interaction=2", "--no-progress"]
    metrics = []
    try:
        for name in ("a", "b"):
            out = tmp_path / name
            args = ("train", "--task", "circle-3", "--interactions", 8, "--threads", 2)
            res = _sili(*args, "--seed", 3, "--out", out, *fast)
            assert res.returncode == 0, res.stderr
            metrics.append(pd.read_csv(out / "metrics.csv").drop(columns="wall_time"))
    finally:
        torch.set_num_threads(1)
    learned = metrics[0][["critic_loss", "latent_loss"]].notna().sum()
    assert (learned >= 4).all()  # SAC and the latent model updated in most interactions
    pd.testing.assert_frame_equal(metrics[0], metrics[1])


def test_the_progress_bar_shows_only_while_there_is_training_left():
    from sili_robots.progress import TrainingProgress

    for completed, shown in ((0, True), (3, True), (5, False)):
        bar = TrainingProgress(5, completed, enabled=True, label="x")
        assert bar.shown is shown
        bar.close()
    assert not TrainingProgress(5, 0, enabled=False).shown


def test_the_progress_bar_goes_to_stderr_so_stdout_is_the_summary_alone(tmp_path):
    done = _sili(
        "train", "--task", "circle-3", "--interactions", 2, *FAST_ARGS, "--out", tmp_path / "r"
    )
    assert done.returncode == 0
    assert json.loads(done.stdout)["interactions"] == 2  # a redirect gets parseable JSON
    assert "circle-3 sili seed 0" in done.stderr and "2/2" in done.stderr


def _doors_module(tmp_path, monkeypatch, module: str, subclass: str) -> None:
    """``module`` (importable) holding ``subclass``: a TwoDoorsEnv subclass's source."""
    (tmp_path / f"{module}.py").write_text(
        f"from sili_robots.examples.two_doors import TwoDoorsEnv\n\n\n{subclass}"
    )
    monkeypatch.syspath_prepend(str(tmp_path))


def test_a_task_class_that_passes_its_keyword_arguments_on_takes_them(tmp_path, monkeypatch):
    _doors_module(
        tmp_path,
        monkeypatch,
        "passing_task",
        "class PassingOn(TwoDoorsEnv):\n"
        "    def __init__(self, **kwargs):\n"
        "        super().__init__(**kwargs)\n",
    )
    args = ["train", "--task", "passing_task:PassingOn", "--interactions", "1", *FAST]
    assert main([*args, "--env-kwarg", "horizon=6", "--out", str(tmp_path / "run")]) == 0
    assert load_trained(tmp_path / "run")[1].unwrapped.horizon == 6


def test_a_task_that_cannot_be_built_is_named_with_its_error(tmp_path, capsys, monkeypatch):
    _doors_module(
        tmp_path,
        monkeypatch,
        "unbuilt_task",
        "class Unbuilt(TwoDoorsEnv):\n"
        "    def __init__(self, horizon=20):\n"
        "        raise RuntimeError(f'no simulator for horizon {horizon}')\n",
    )
    args = ["train", "--task", "unbuilt_task:Unbuilt", "--interactions", "1", *FAST]
    assert main([*args, "--env-kwarg", "horizon=6", "--out", str(tmp_path / "run")]) == 2
    assert (  # whatever the constructor raises is named, no traceback, no run folder
        "task 'unbuilt_task:Unbuilt' cannot be built with horizon=6: RuntimeError: no "
        "simulator for horizon 6" in capsys.readouterr().err
    )
    assert not (tmp_path / "run").exists()
    (tmp_path / "half_written.py").write_text("class Half(:\n")  # found, but does not compile
    done = _sili("rollout", "half_written:Half", "--policy", "random")
    assert done.returncode == 2 and "(SyntaxError: invalid syntax" in done.stderr
    assert "importing half_written failed: fix it, or install what it imports" in done.stderr
    (tmp_path / "bad_attr.py").write_text("import os\n\nX = os.no_such_attribute\n")
    done = _sili("rollout", "bad_attr:X", "--policy", "random")  # raised while importing
    assert done.returncode == 2 and "importing bad_attr failed: fix it" in done.stderr
    done = _sili("rollout", "unbuilt_task:Unbuilt", "--policy", "still")
    assert done.returncode == 2 and "RuntimeError: no simulator for horizon 20" in done.stderr
    _doors_module(
        tmp_path,
        monkeypatch,
        "wide_task",
        "class Wide(TwoDoorsEnv):\n"
        "    def _make_action_space(self):\n"
        "        from gymnasium import spaces\n\n"
        "        return spaces.Box(-2.0, 2.0, (1,))\n",
    )
    assert main([*args[:2], "wide_task:Wide", *args[3:], "--out", str(tmp_path / "run")]) == 2
    assert "must be bounded by -1 and 1 (agents act through tanh)" in capsys.readouterr().err
    assert not (tmp_path / "run").exists()


def test_env_kwargs_reach_the_task_and_a_bad_one_is_named(tmp_path, capsys):
    doors = "sili_robots.examples.two_doors:TwoDoorsEnv"
    out = tmp_path / "doors"
    args = ["train", "--task", doors, "--interactions", "2", *FAST]
    assert main([*args, "--env-kwarg", "horizon=6", "--out", str(out)]) == 0
    cfg, env, _, _ = load_trained(out)
    assert cfg.env_kwargs == {"horizon": 6} and env.unwrapped.horizon == 6
    assert len(pd.read_csv(out / "metrics.csv")) == 2
    capsys.readouterr()
    assert main([*args, "--env-kwarg", "doors=3", "--out", str(tmp_path / "bad")]) == 2
    err = capsys.readouterr().err
    assert "takes no argument doors (--controller, --env-kwarg); its arguments: horizon" in err
    assert main([*args, "--env-kwarg", "horizon=[6]", "--out", str(tmp_path / "bad")]) == 2
    err = capsys.readouterr().err  # a value the task cannot take: the task's own message
    assert "horizon must be an integer in [1, 10000], got [6]" in err
    assert not (tmp_path / "bad").exists()


def test_a_run_directory_is_replaced_only_with_overwrite(tmp_path, capsys):
    out = tmp_path / "run"
    args = ["train", "--task", "circle-3", "--method", "sac", *FAST, "--out", str(out)]
    assert main([*args, "--interactions", "4", "--seed", "1"]) == 0
    (out / "notes.txt").write_text("mine")
    capsys.readouterr()
    assert main([*args, "--interactions", "2", "--seed", "2"]) == 2
    said = f"{out} already holds a run; --resume {out} continues it, --overwrite replaces it"
    assert said in capsys.readouterr().err
    assert len(pd.read_csv(out / "metrics.csv")) == 4  # untouched
    assert main([*args, "--interactions", "2", "--seed", "2", "--overwrite"]) == 0
    assert json.loads((out / "config.json").read_text())["run"]["seed"] == 2
    assert len(pd.read_csv(out / "metrics.csv")) == 2
    assert (out / "notes.txt").read_text() == "mine"  # only the run's own files are replaced
    (out / "checkpoint.pt").unlink()  # not "--resume continues it": there is nothing to
    assert main([*args, "--interactions", "2"]) == 2
    said = f"{out} already holds a finished run kept without its checkpoint.pt (it has summary.json"
    assert said + "); --overwrite replaces it" in capsys.readouterr().err
    (out / "summary.json").unlink()  # as a run stopped or diverged before its first checkpoint
    assert main([*args, "--interactions", "2"]) == 2
    said = f"{out} already holds a run with no checkpoint yet; --overwrite replaces it"
    assert said in capsys.readouterr().err  # (--resume would train it from the start again)


def test_a_new_run_never_goes_into_a_folder_of_other_files(tmp_path, capsys):
    out = tmp_path / "mine"
    out.mkdir()
    (out / "metrics.csv").write_text("my own table\n")
    (out / "notes.txt").write_text("mine")
    args = ["train", "--task", "circle-3", "--method", "sac", *FAST, "--interactions", "2"]
    for extra in ([], ["--overwrite"]):
        assert main([*args, "--out", str(out), *extra]) == 2
        assert "is not a run but holds files (notes.txt)" in capsys.readouterr().err
    assert (out / "metrics.csv").read_text() == "my own table\n"
    empty = tmp_path / "empty"
    empty.mkdir()
    (empty / ".gitkeep").write_text("")  # hidden files are nobody's results
    assert main([*args, "--out", str(empty)]) == 0
    # a run's files left without their config (a removal cut short): replaced only on request
    (empty / "config.json").unlink()
    assert main([*args, "--out", str(empty)]) == 2
    assert "holds a run's files (checkpoint.pt, metrics.csv, summary.json) but no config.json" in (
        capsys.readouterr().err
    )
    assert main([*args, "--out", str(empty), "--overwrite", "--seed", "3"]) == 0
    assert json.loads((empty / "config.json").read_text())["run"]["seed"] == 3


def test_a_run_that_fails_before_writing_leaves_no_folder_it_made(tmp_path, capsys, monkeypatch):
    """Too little memory for the agent (torch's own failure) or a stop while the run is set up:
    the folders the command made for it go again; a folder given, or one written to, stays."""
    args = ["train", "--task", "circle-3", "--method", "sac", *FAST, "--interactions", "2"]
    monkeypatch.setattr(
        training, "_start_or_resume", lambda *_a: torch.empty(2**62, dtype=torch.uint8)
    )
    for out in (tmp_path / "new" / "run", tmp_path / "new" / ".." / "other" / "run"):
        assert main([*args, "--out", str(out)]) == 1
        assert "out of memory" in capsys.readouterr().err
        assert list(tmp_path.iterdir()) == [], out
    given = tmp_path / "given"
    given.mkdir()
    assert main([*args, "--out", str(given / "run")]) == 1
    assert list(tmp_path.iterdir()) == [given] and list(given.iterdir()) == []

    def written_then_stopped(_cfg, run_dir, *_a):
        (run_dir / "config.json").write_text("{}")
        raise KeyboardInterrupt

    monkeypatch.setattr(training, "_start_or_resume", written_then_stopped)
    assert main([*args, "--out", str(tmp_path / "new" / "run")]) == 130
    assert (tmp_path / "new" / "run" / "config.json").read_text() == "{}"


def test_a_checkpoint_write_cut_short_leaves_the_previous_one_and_names_the_file(tmp_path):
    """The write goes to a side file that replaces the checkpoint only once it is complete; a
    disk that refuses it part-way gives the file's name and the cause (torch's own writer said
    "unexpected pos")."""
    state = {"agent": {"latents": {"Z": np.zeros(2)}, "addons": {}}, "interaction": 5}
    save_checkpoint(tmp_path, state)
    size = (tmp_path / "checkpoint.pt").stat().st_size
    bigger = {**state, "interaction": 10, "replay": np.zeros(10_000)}
    with pytest.raises(OSError) as refused, file_size_limit(size + 1000):
        save_checkpoint(tmp_path, bigger)
    assert refused.value.filename == str(tmp_path / "checkpoint.pt")
    assert refused.value.strerror == "File too large"
    assert torch.load(tmp_path / "checkpoint.pt", weights_only=False)["interaction"] == 5
    assert sorted(p.name for p in tmp_path.iterdir()) == ["checkpoint.pt"]


def test_a_full_disk_ends_training_in_one_line_and_the_run_resumes(tmp_path, monkeypatch):
    """A write the disk refuses (past the file size limit here, as a full disk refuses it) ends
    the command naming the file, with no traceback; the last checkpoint is kept, and the command
    printed to go on works as given (a name with a leading dash too)."""
    monkeypatch.chdir(tmp_path)
    run = Path("-run")
    args = ["--task", "circle-3", "--method", "sac", *FAST]
    assert _sili("train", *args, "--interactions", 2, "--out=-run").returncode == 0
    before = (run / "checkpoint.pt").read_bytes()
    with file_size_limit(len(before) // 2):
        res = _sili("train", "--resume=-run", "--interactions", 4)
    assert res.returncode == 1, res.stderr
    assert f"sili train: error: {run / 'checkpoint.pt'}: File too large" in res.stderr
    said = "once the disk takes writes again, continue the run with: "
    assert f"{said}sili train --resume ./-run\n" in res.stderr
    assert (run / "checkpoint.pt").read_bytes() == before
    assert not list(run.glob("*.tmp"))
    command = res.stderr.split(said)[1].splitlines()[0].split()
    assert _sili(*command[1:], "--interactions", 4, "--no-progress").returncode == 0
    assert pd.read_csv(run / "metrics.csv")["interaction"].tolist() == [0, 1, 2, 3]
    assert run_state(run) == "done"


def test_a_history_row_cut_short_is_refused_not_trained_on(tmp_path):
    """A trained row of metrics.csv cut short (by hand, or a disk) would be kept as it is, its
    missing values blank; rows past the checkpoint are the run's to drop."""
    run = tmp_path / "run"
    args = ["--task", "circle-3", "--method", "sac", "--interactions", 3, *FAST, "--out", run]
    assert _sili("train", *args).returncode == 0
    whole = (run / "metrics.csv").read_bytes()
    lines = whole.splitlines(keepends=True)  # the header and interactions 0, 1, 2
    for damaged, line in (
        (b"".join([*lines[:2], lines[2][:8] + b"\r\n", lines[3]]), 3),  # interaction 1
        (whole[:-2], 4),  # the last row's end
    ):
        (run / "metrics.csv").write_bytes(damaged)
        res = _sili("train", "--resume", run, "--interactions", 4)
        assert res.returncode == 2, res.stderr
        said = f"{run / 'metrics.csv'} is damaged (line {line} is cut short, a row of the 3"
        assert said in res.stderr
        assert (run / "metrics.csv").read_bytes() == damaged
    (run / "metrics.csv").write_bytes(whole + lines[3][:8])  # a row past the checkpoint
    assert len(read_metrics(run / "metrics.csv")) == 3  # readers leave it out as resume does
    filled = b",".join(lines[3].split(b",")[:9])  # interaction to beta, and latent_loss
    (run / "metrics.csv").write_bytes(whole + filled + b",0.1")  # cut in critic_loss
    assert len(read_metrics(run / "metrics.csv")) == 3  # not a trained row (`sili runs`)
    (run / "metrics.csv").write_bytes(whole + b"3,-")  # cut inside a number
    rows = read_metrics(run / "metrics.csv")
    assert rows.dtypes.equals(pd.read_csv(io.BytesIO(whole)).dtypes)  # numbers, as written
    assert rows["task_reward"].mean() < 0
    assert _sili("train", "--resume", run, "--interactions", 4).returncode == 0
    assert pd.read_csv(run / "metrics.csv")["interaction"].tolist() == [0, 1, 2, 3]


def test_a_history_the_disk_refuses_still_closes_the_task(tmp_path, monkeypatch):
    """The history's close fails again after a refused row (the row is still unwritten): the
    task (a SUMO or MuJoCo simulation) is closed all the same."""
    from sili_robots.build import make_run_config

    closed = []
    built = training.make_run_env

    def tracked(cfg, recorded_in=None):
        env = built(cfg, recorded_in)
        original = env.close
        env.close = lambda: closed.append(1) or original()
        return env

    monkeypatch.setattr(training, "make_run_env", tracked)
    cfg = make_run_config("circle-3", "sac", 0, 60, settings=FAST_AGENT, checkpoint_every=1000)
    with pytest.raises(OSError) as refused, file_size_limit(4000):  # config.json fits
        training.train(cfg, tmp_path / "run", progress=False)
    assert refused.value.filename == str(tmp_path / "run" / "metrics.csv")
    assert closed == [1]


def test_a_name_too_long_for_the_file_system_is_bad_input(tmp_path):
    """Checked where the path is read (pathlib's own checks say "no such file" from Python
    3.14); the operating system's refusal of a longer path is named as well."""
    long = tmp_path / ("b" * 256)
    for command in (["eval", long], ["train", "--task", "circle-3", *FAST, "--out", long]):
        res = _sili(*command)
        assert res.returncode == 2, res.stderr
        assert f"{long}: a name in it is too long (256 bytes; most file systems allow 255)" in (
            res.stderr
        )
    deep = Path(tmp_path, *["d" * 200] * 25)  # each name allowed, the whole over PATH_MAX
    res = _sili("eval", deep)
    assert res.returncode == 2, res.stderr
    assert f"sili eval: error: {deep}: the path, or a name in it, is too long" in res.stderr


def test_a_run_kept_without_its_checkpoint_is_not_trained_again(tmp_path, capsys):
    """A collected run (config, summary, gzipped metrics) cannot be resumed or extended: it would
    start over and replace its results. One killed before its first checkpoint starts over."""
    out = tmp_path / "run"
    args = ["train", "--task", "circle-3", "--method", "sac", "--interactions", "3", *FAST]
    assert main([*args, "--out", str(out)]) == 0
    (out / "checkpoint.pt").unlink()
    kept = {p.name: p.read_bytes() for p in out.iterdir()}
    capsys.readouterr()
    for extra in ([], ["--interactions", "6"]):
        assert main(["train", "--resume", str(out), *extra, "--no-progress"]) == 2
        err = capsys.readouterr().err
        assert f"{out} holds a finished run without its checkpoint.pt (it has summary.json)" in err
        assert {p.name: p.read_bytes() for p in out.iterdir()} == kept
    assert main(["eval", str(out)]) == 2
    assert "no checkpoint to resume, extend or evaluate it from" in capsys.readouterr().err
    (out / "summary.json").unlink()  # as if killed before its first checkpoint
    assert main(["train", "--resume", str(out), "--no-progress"]) == 0
    assert len(pd.read_csv(out / "metrics.csv")) == 3


def test_a_run_being_extended_is_unfinished_until_it_ends(tmp_path, monkeypatch):
    """A finished run's summary goes when it resumes: one killed while extended is resumable,
    not counted finished (sweeps and collect read the summary as "done")."""
    out = tmp_path / "run"
    args = ["train", "--task", "circle-3", "--method", "sac", "--interactions", "3", *FAST]
    assert main([*args, "--out", str(out)]) == 0
    extend(out, 5)

    def killed(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(training, "play_interaction", killed)
    with pytest.raises(KeyboardInterrupt):
        resume(out, progress=False)
    assert not (out / "summary.json").exists() and run_state(out) == "resumable"
    monkeypatch.undo()
    resume(out, progress=False)
    assert json.loads((out / "summary.json").read_text())["interactions"] == 5
    # stopped after the extension was recorded but before it trained: resumable, not done
    monkeypatch.setattr(training, "record_continuation", killed)
    with pytest.raises(KeyboardInterrupt):
        resume(out, progress=False, interactions=6)
    assert json.loads((out / "config.json").read_text())["run"]["interactions"] == 6
    assert run_state(out) == "resumable"
    # stopped before the game was restored: the run is left as it was
    monkeypatch.setattr(training, "resume_game", killed)
    with pytest.raises(KeyboardInterrupt):
        resume(out, progress=False, interactions=8)
    assert json.loads((out / "config.json").read_text())["run"]["interactions"] == 6
    # as earlier versions left it (the target raised, the shorter summary kept): not done
    (out / "summary.json").write_text(json.dumps({"interactions": 5}))
    assert run_state(out) == "resumable"


def test_extending_a_run_keeps_the_record_of_how_it_began(tmp_path):
    out = tmp_path / "run"
    args = ["train", "--task", "circle-3", "--method", "sac", "--interactions", "2", *FAST]
    assert main([*args, "--out", str(out)]) == 0
    record = json.loads((out / "config.json").read_text())
    record["versions"]["torch"] = "0.0-recorded"
    (out / "config.json").write_text(json.dumps(record))
    extend(out, 3)
    after = json.loads((out / "config.json").read_text())
    assert after["run"]["interactions"] == 3 and after["versions"]["torch"] == "0.0-recorded"
    # going on in other software is recorded where it happened, once
    assert main(["train", "--resume", str(out), "--no-progress"]) == 0
    assert main(["train", "--resume", str(out), "--interactions", "4", "--no-progress"]) == 0
    after = json.loads((out / "config.json").read_text())
    (continued,) = after["continued"]
    assert (
        continued["from_interaction"] == 2 and continued["versions"]["torch"] == torch.__version__
    )
    assert after["versions"]["torch"] == "0.0-recorded"


def test_a_run_a_sweep_worker_is_training_is_not_resumed_beside_it(tmp_path, capsys, monkeypatch):
    out = tmp_path / "run"
    args = ["train", "--task", "circle-3", "--method", "sac", "--interactions", "2", *FAST]
    assert main([*args, "--out", str(out)]) == 0
    host = socket.gethostname()
    (out / "worker.json").write_text(json.dumps({"pid": os.getpid(), "host": host}))
    capsys.readouterr()
    assert main(["train", "--resume", str(out), "--interactions", "3", "--no-progress"]) == 2
    assert f"is being trained by process {os.getpid()} (a sweep's worker" in capsys.readouterr().err
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    assert main([*args, "--seed", "1", "--out", str(out), "--overwrite"]) == 2  # not cleared
    assert f"{out} is being trained by process {os.getpid()}" in capsys.readouterr().err
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before
    gone = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], check=True,
                          capture_output=True, text=True)  # fmt: skip
    (out / "worker.json").write_text(json.dumps({"pid": int(gone.stdout), "host": host}))
    claims = []  # sili train claims the run while it trains it, as a sweep's worker does
    play = training.play_interaction

    def watched(*args, **kwargs):
        claims.append(json.loads((out / "worker.json").read_text())["pid"])
        return play(*args, **kwargs)

    monkeypatch.setattr(training, "play_interaction", watched)
    assert main(["train", "--resume", str(out), "--interactions", "3", "--no-progress"]) == 0
    assert claims == [os.getpid()] and not (out / "worker.json").exists()


def test_more_threads_than_cores_is_trained_with_a_note(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {0})  # one core to use
    args = ["train", "--task", "circle-3", "--method", "sac", "--interactions", "1", *FAST]
    assert main([*args, "--threads", "2", "--out", str(tmp_path / "two")]) == 0
    note = "sili train: note: --threads 2 is more than the 1 CPU(s) this process may use: the"
    assert note in capsys.readouterr().err
    assert json.loads((tmp_path / "two" / "config.json").read_text())["run"]["threads"] == 2
    assert main(["train", "--resume", str(tmp_path / "two"), "--interactions", "2"]) == 0
    assert note in capsys.readouterr().err  # a resumed run keeps its threads, and the note
    assert main([*args, "--out", str(tmp_path / "one")]) == 0
    assert "note: --threads" not in capsys.readouterr().err


def test_kernels_slow_on_this_machine_are_trained_with_a_note(tmp_path, capsys, monkeypatch):
    """A bfloat16 run resumed on a machine without bfloat16 units keeps its precision (its
    numbers depend on it) and says how much slower it is there, from the kernel timings."""
    from agent_helpers import timed_kernels

    from sili_robots.agent.matmul import onednn_available

    close = {"onednn": 1.2e-3, "aten": 1e-3}  # no note
    timed_kernels(monkeypatch, tmp_path / "cache", close, {"float32": 1e-3, "bfloat16": 1.03e-2})
    args = ["train", "--task", "circle-3", "--method", "sac", "--interactions", "1", *FAST]
    run = tmp_path / "bf16"
    assert main([*args, "--set", "sac.precision=bfloat16", "--out", str(run)]) == 0
    note = (
        "sili train: note: sac.precision=bfloat16 is 10.3x as slow as float32 on this machine "
        "(as timed for its default); the run keeps it, as its numbers depend on it"
    )
    assert note in capsys.readouterr().err
    assert main(["train", "--resume", str(run), "--interactions", "2"]) == 0
    assert note in capsys.readouterr().err
    assert json.loads((run / "config.json").read_text())["run"]["agent"]["sac"]["precision"] == (
        "bfloat16"
    )
    for again in ([], ["--interactions", "2"]):
        assert main(["train", "--resume", str(run), *again]) == 0
        assert "as slow as" not in capsys.readouterr().err  # done: nothing trains
    library = "onednn" if onednn_available() else "aten"
    assert main([*args, "--set", f"matmul={library}", "--out", str(tmp_path / "plain")]) == 0
    assert "as slow as" not in capsys.readouterr().err  # float32 by default, oneDNN 1.2x


def test_a_record_or_history_damaged_in_its_content_exits_2_naming_the_file(tmp_path):
    run = tmp_path / "run"
    args = ["--task", "circle-3", "--method", "sac", "--interactions", 2, *FAST, "--out", run]
    assert _sili("train", *args).returncode == 0
    record = json.loads((run / "config.json").read_text())
    for damage in (
        {"bogus": 1},
        {"agent": None},
        {"checkpoint_every": 0},
        {"threads": "x"},
        {"method": "foo"},
        {"env_kwargs": [1]},
        {"env_kwargs": {"bogus": 1}},  # (was a TypeError from the task's constructor)
        {"task": "nosuch-task"},  # beside a valid task_id: the tables would list "nosuch-task"
        {"agent": {**record["run"]["agent"], "sac": {"lr": {"points": [[0, "a"]]}}}},
        {"agent": {**record["run"]["agent"], "sac": {**record["run"]["agent"]["sac"], "lr": -5}}},
    ):
        (run / "config.json").write_text(json.dumps({**record, "run": {**record["run"], **damage}}))
        for command in (["eval", run], ["train", "--resume", run, "--interactions", 3]):
            res = _sili(*command)
            assert res.returncode == 2, (damage, res.stderr)
            assert f"{run / 'config.json'} is damaged" in res.stderr, (damage, res.stderr)
    doors = tmp_path / "doors"  # a task class's run: its arguments named where it is built
    train_doors = ["--task", "sili_robots.examples.two_doors:TwoDoorsEnv", "--method", "sac"]
    assert _sili("train", *train_doors, "--interactions", 1, *FAST, "--out", doors).returncode == 0
    kept = json.loads((doors / "config.json").read_text())
    kept["run"]["env_kwargs"] = {"bogus": 1}  # an argument the class dropped since
    (doors / "config.json").write_text(json.dumps(kept))
    state = torch.load(doors / "checkpoint.pt", weights_only=False)
    state["run"]["env_kwargs"] = {"bogus": 1}  # recorded with the run as it was trained
    torch.save(state, doors / "checkpoint.pt")
    res = _sili("eval", doors)
    assert res.returncode == 2 and "Traceback" not in res.stderr, res.stderr
    assert "takes no argument bogus (the run's env_kwargs); its arguments: horizon" in res.stderr
    # a setting this version does not know, from a newer one: not damage, and no retraining
    newer = {"run": {**record["run"], "later_setting": 1}, "versions": {"sili_robots": "9.0.0"}}
    (run / "config.json").write_text(json.dumps(newer))
    res = _sili("eval", run)
    assert res.returncode == 2 and "is damaged" not in res.stderr, res.stderr
    assert "written by sili-robots 9.0.0, newer than this one" in res.stderr, res.stderr
    assert "update sili-robots" in res.stderr
    (run / "config.json").write_text(json.dumps(record))
    checkpoint = (run / "checkpoint.pt").read_bytes()
    torch.save({"agent": None, "interaction": 2}, run / "checkpoint.pt")
    res = _sili("eval", run)
    assert res.returncode == 2 and f"{run / 'checkpoint.pt'} is damaged" in res.stderr
    (run / "checkpoint.pt").write_bytes(checkpoint)
    held = tmp_path / "held" / "runs" / "circle-3__sac__s0"  # as a collection holds it
    shutil.copytree(run, held)
    for content in (
        "",
        "a,b\n1,2\n",
        "\x00\xff\xfe",
        "interaction,task_reward,strategy_changed\n0,x,0\n",
        "interaction,task_reward,strategy_changed,strategy_id\n0,-1.5,0,1\n1,-6\n2,-1,0,1\n",
    ):
        for where in (run, held):
            (where / "metrics.csv").write_bytes(content.encode("latin-1"))
        for command in (["runs", held.parents[1]], ["plot", held.parents[1]]):
            res = _sili(*command)
            assert res.returncode == 2, (content, command, res.stderr)
            assert f"{held / 'metrics.csv'} is damaged" in res.stderr, (content, res.stderr)
        if content.startswith(("a", "\x00")):  # what resuming would append to
            res = _sili("train", "--resume", run, "--interactions", 3)
            assert res.returncode == 2 and f"{run / 'metrics.csv'} is damaged" in res.stderr


def test_a_stop_file_stops_the_run_once_its_interaction_is_saved(tmp_path, monkeypatch):
    """How a sweep stops its runs: the interaction under way is logged and checkpointed; a
    stop asked while the run was set up plays none."""
    from sili_robots.build import make_run_config

    cfg = make_run_config("circle-3", "sac", 0, 5, settings=FAST_AGENT)
    stop = tmp_path / "stop"
    stop.touch()
    with pytest.raises(KeyboardInterrupt, match="asked the run to stop"):
        training.train(cfg, tmp_path / "run", progress=False, stop_file=stop)
    assert load_checkpoint(tmp_path / "run") is None
    assert len(pd.read_csv(tmp_path / "run" / "metrics.csv")) == 0
    stop.unlink()
    play = training.play_interaction

    def asked_during_the_first(*args, **kwargs):
        stop.touch()  # as the sweep does while the interaction is played
        return play(*args, **kwargs)

    monkeypatch.setattr(training, "play_interaction", asked_during_the_first)
    with pytest.raises(KeyboardInterrupt, match="asked the run to stop"):
        training.train(cfg, tmp_path / "run", progress=False, stop_file=stop)
    monkeypatch.setattr(training, "play_interaction", play)
    assert load_checkpoint(tmp_path / "run")["interaction"] == 1
    assert len(pd.read_csv(tmp_path / "run" / "metrics.csv")) == 1
    stop.unlink()
    training.train(cfg, tmp_path / "run", resume=True, progress=False, stop_file=stop)
    assert len(pd.read_csv(tmp_path / "run" / "metrics.csv")) == 5


def test_training_into_a_log_writes_plain_progress_lines(tmp_path, monkeypatch):
    """Into a log (nohup, CI) rich's bar draws only when it stops: the log stayed empty for
    the whole run; now a plain line comes every LOG_EVERY seconds, and one at the end."""
    from sili_robots import progress

    monkeypatch.setattr(progress, "LOG_EVERY", 0.0)
    args = ["train", "--task", "circle-3", "--method", "sac", "--interactions", "3"]
    done = _sili(*args, *FAST_ARGS, "--out", tmp_path / "run")  # stderr: a StringIO, no terminal
    assert done.returncode == 0, done.stderr
    lines = [line for line in done.stderr.splitlines() if " interactions, reward " in line]
    assert [line.split(":")[1].split()[0] for line in lines] == ["1/3", "2/3", "3/3", "3/3"]
    assert lines[0].startswith("circle-3 sac seed 0: 1/3 interactions, reward ")
    assert "\x1b" not in done.stderr and "━" not in done.stderr  # no bar, no escape codes


def test_a_narrow_terminal_shortens_the_label_not_the_numbers(monkeypatch):
    import io

    from rich.console import Console

    from sili_robots import progress

    out = io.StringIO()
    console = Console(file=out, width=80, force_terminal=True, force_interactive=True)
    monkeypatch.setattr(progress, "Console", lambda **_: console)
    bar = progress.TrainingProgress(2500, 189, label="circle-unequal oracle seed 12")
    bar.advance(-47.87, 0.01)
    bar.close()
    drawn = re.sub(r"\x1b\[[0-9;?]*[A-Za-z]", "", out.getvalue()).replace("\r", "\n")
    last = [line for line in drawn.splitlines() if line.strip()][-1]
    assert "190/2500 reward   -47.87 stable 0.01" in last, last


def test_a_resumed_run_s_wall_time_goes_on_from_its_checkpoint(tmp_path, monkeypatch):
    """A resumed run's wall_time (metrics.csv, summary.json's wall_time_s) counts the time
    before the stop too: 100 s between clock reads in a first session, the real clock after."""
    import itertools
    import types

    from sili_robots.build import make_run_config

    ticks = itertools.count(step=100.0)
    monkeypatch.setattr(training, "time", types.SimpleNamespace(perf_counter=lambda: next(ticks)))
    cfg = make_run_config("circle-3", "sac", 0, 2, settings=FAST_AGENT)
    training.train(cfg, tmp_path / "run", progress=False)
    before = pd.read_csv(tmp_path / "run" / "metrics.csv")["wall_time"].iloc[-1]
    assert before >= 100
    monkeypatch.undo()
    training.resume(tmp_path / "run", progress=False, interactions=4)
    wall = pd.read_csv(tmp_path / "run" / "metrics.csv")["wall_time"]
    assert (wall.diff().dropna() >= 0).all(), wall.tolist()
    assert json.loads((tmp_path / "run" / "summary.json").read_text())["wall_time_s"] >= before


def test_a_stop_file_in_the_last_interaction_leaves_the_run_finished(tmp_path, monkeypatch):
    """Asked to stop (a sweep's stop file) in its last interaction, the run finishes, summary
    written, as at a stop signal there: a sweep then counts it done."""
    from sili_robots.build import make_run_config

    cfg = make_run_config("circle-3", "sac", 0, 2, settings=FAST_AGENT)
    stop, play, calls = tmp_path / "stop", training.play_interaction, []

    def asked_during_the_last(*args, **kwargs):
        calls.append(1)
        if len(calls) == 2:
            stop.touch()
        return play(*args, **kwargs)

    monkeypatch.setattr(training, "play_interaction", asked_during_the_last)
    try:
        training.train(cfg, tmp_path / "run", progress=False, stop_file=stop)
    except KeyboardInterrupt as stopped:  # (pytest would end the whole session on it)
        pytest.fail(f"a stop in the last interaction raised: {stopped}")
    assert (tmp_path / "run" / "summary.json").is_file()
    assert run_state(tmp_path / "run") == "done"


def test_a_resumed_run_s_log_line_counts_its_time_left_at_this_session_s_rate(monkeypatch, capsys):
    """Resumed at 90 of 100, one interaction in 10 s: 9 left at 10 s each, 0:01:30 (not 1 s at
    the rate from interaction 0, nor 1,000 s for all 100)."""
    from sili_robots import progress

    monkeypatch.setattr(progress, "LOG_EVERY", 1e9)  # only the closing line
    clock = {"t": 0.0}
    monkeypatch.setattr(progress.time, "monotonic", lambda: clock["t"])
    bar = progress.TrainingProgress(100, 90, label="x")
    assert bar.shown
    clock["t"] = 10.0
    bar.advance(1.0, 1.0)
    bar.close()
    line = [ln for ln in capsys.readouterr().err.splitlines() if "interactions" in ln][-1]
    assert "91/100 interactions" in line and line.endswith("0:01:30 left"), line


def test_a_run_in_a_runs_folder_outside_a_sweep_writes_no_tables_above_it(tmp_path):
    """``sili train --resume`` rebuilds a sweep's tables only for a run of a sweep: a run that
    merely sits in a folder named ``runs`` leaves the folder above it alone."""
    project = tmp_path / "project"
    run = project / "runs" / "r1"
    new = ("train", "--task", "circle-3", "--interactions", 2, *FAST_ARGS, "--no-progress")
    assert _sili(*new, "--out", run).returncode == 0
    resumed = _sili("train", "--resume", run, "--interactions", 3, "--no-progress")
    assert resumed.returncode == 0, resumed.stderr
    assert "tables were not rebuilt" not in resumed.stderr
    assert sorted(p.name for p in project.iterdir()) == ["runs"]  # no results.csv, runs.csv


def test_a_run_s_files_with_its_tb_folder_but_no_config_are_not_trained_over(tmp_path):
    """A run's metrics.csv and tb/ left without config.json were trained over without asking."""
    run = tmp_path / "run"
    (run / "tb").mkdir(parents=True)
    (run / "metrics.csv").write_text("interaction\n0\n")
    done = _sili("train", "--task", "circle-3", "--interactions", "1", *FAST, "--out", run)
    assert done.returncode == 2
    assert "holds a run's files (metrics.csv, tb) but no config.json" in done.stderr
    assert (run / "metrics.csv").read_text() == "interaction\n0\n"
