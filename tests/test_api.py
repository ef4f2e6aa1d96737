"""The Python API: SILI(env).learn / predict / save / load, on a registered task, on a user's
task class, and on a run of the CLI."""

from __future__ import annotations

import csv
import gc
import json
import pickle
import re
import shutil
import sys
import warnings

import numpy as np
import pytest
from fast_settings import FAST_AGENT

from sili_robots import SILI, training
from sili_robots.agent import SILIAgent
from sili_robots.build import make_run_config, task_class
from sili_robots.cli import main
from sili_robots.errors import ConfigError, UnreadSettingWarning
from sili_robots.evaluation import evaluate
from sili_robots.examples.two_doors import TwoDoorsEnv
from sili_robots.tasks import make_task

TWO_DOORS = "sili_robots.examples.two_doors:TwoDoorsEnv"


def _play(model: SILI, interactions: int) -> list[np.ndarray]:
    """Greedy actions over whole interactions played on ``model.env``."""
    actions = []
    obs, _ = model.env.reset()
    for _ in range(interactions):
        done = False
        while not done:
            action = model.predict(obs, deterministic=True)
            actions.append(action)
            obs, _, terminated, truncated, _ = model.env.step(action)
            done = terminated or truncated
        obs, _ = model.env.reset()
    return actions


def test_learn_predict_save_load_on_a_registered_task(tmp_path):
    model = SILI("sili/Circle3-v0", method="sili", seed=0, settings=FAST_AGENT)
    assert model.learn(interactions=5) is model
    assert model.agent.buffer.n == 5
    model.learn(interactions=3)  # continues the same run
    metrics = (model.run_dir / "metrics.csv").read_text().splitlines()
    assert len(metrics) == 1 + 8
    saved = model.save(tmp_path / "model")
    loaded = SILI.load(saved)
    # the same agent and game: the same greedy actions, and the latent carried across
    # interactions (each reset of model.env hands the agent the interaction just played)
    a, b = _play(model, 2), _play(loaded, 2)
    np.testing.assert_allclose(np.stack(a), np.stack(b), atol=1e-6)
    assert loaded.agent.buffer.n == 8 + 2 and len(loaded.agent.Z) == 8 + 2 + 1
    assert loaded.evaluate(3)["interactions"] == 3


def test_a_users_task_class_trains_through_the_api_and_the_cli(tmp_path):
    env = TwoDoorsEnv(horizon=8)
    model = SILI(env, method="lili", seed=1, settings=FAST_AGENT, run_dir=tmp_path / "api")
    model.learn(interactions=4)
    config = json.loads((tmp_path / "api" / "config.json").read_text())["run"]
    assert config["task"] == TWO_DOORS and config["env_kwargs"] == {"horizon": 8}
    action = model.predict(model.env.reset()[0])
    assert action.shape == (1,) and np.all(np.abs(action) <= 1)
    args = ["train", "--task", TWO_DOORS, "--method", "sili", "--interactions", "4"]
    fast = [x for k, v in FAST_AGENT.items() for x in ("--set", f"{k}={v}")]
    assert main([*args, *fast, "--out", str(tmp_path / "cli"), "--no-progress"]) == 0
    loaded = SILI.load(tmp_path / "cli")  # a CLI run loads and predicts
    assert loaded.cfg.task == TWO_DOORS and loaded.predict(loaded.env.reset()[0]).shape == (1,)


def test_api_refuses_what_it_cannot_use(tmp_path):
    import gymnasium as gym

    with pytest.raises(ConfigError, match="does not follow the repeated-interaction contract"):
        SILI(gym.make("Pendulum-v1"))
    with pytest.raises(ConfigError, match="circle-3 was built with variant='8', another task"):
        SILI(gym.make("sili/Circle3-v1", variant="8"))  # could never be loaded as circle-3
    model = SILI("circle-3", method="sac", settings=FAST_AGENT)
    with pytest.raises(ConfigError, match="nothing to save yet"):
        model.save(tmp_path / "x")
    with pytest.raises(ConfigError, match=r"interactions must be an integer in \[1, 2147483647\]"):
        model.learn(0)
    with pytest.raises(ConfigError, match="nothing to evaluate yet: call learn"):
        model.evaluate(2)
    model.learn(1)
    with pytest.raises(ConfigError, match=r"in \[1, 2147483646\], got 2147483647"):
        model.learn(2**31 - 1)  # a run's count stays within what its tables hold
    for bad in (0, -2, 1.5):  # no NaN summaries of nothing
        with pytest.raises(ConfigError, match=f"interactions must be an integer >= 1, got {bad}"):
            model.evaluate(bad)
    with pytest.raises(ConfigError, match=r"method 'lili' fixes sili\.beta"):
        SILI("circle-3", method="lili", settings={"beta": 0.7})
    with pytest.raises(ConfigError, match=r"obs has shape \(2,\); this model observes shape"):
        model.predict([0.0, 0.0])
    with pytest.raises(ConfigError, match=r"takes no argument farr \(env_kwargs\); its arg"):
        SILI(TWO_DOORS, env_kwargs={"farr": 2})


def test_a_new_model_never_trains_over_a_run_or_into_a_folder_of_other_files(tmp_path):
    run, notes = tmp_path / "run", tmp_path / "notes"
    SILI(TWO_DOORS, method="sac", settings=FAST_AGENT, run_dir=run).learn(3)
    with pytest.raises(ConfigError, match=r"already holds a run; SILI.load\(.*\) continues it"):
        SILI("circle-3", settings=FAST_AGENT, run_dir=run)
    notes.mkdir()
    (notes / "paper.tex").write_text("mine")
    with pytest.raises(ConfigError, match=r"holds files \(paper\.tex\); give run_dir a new"):
        SILI("circle-3", settings=FAST_AGENT, run_dir=notes)
    assert len((run / "metrics.csv").read_text().splitlines()) == 1 + 3  # untouched
    late = SILI("circle-3", method="sac", settings=FAST_AGENT, run_dir=tmp_path / "late")
    shutil.copytree(run, tmp_path / "late")  # a run came in after the model was made
    before = {p.name: p.read_bytes() for p in (tmp_path / "late").iterdir()}
    for _ in range(2):  # refused, and again: the model is as it was
        with pytest.raises(ConfigError, match="already holds a run"):
            late.learn(2)
    assert {p.name: p.read_bytes() for p in (tmp_path / "late").iterdir()} == before
    model = SILI("circle-3", method="sac", settings=FAST_AGENT, run_dir=run, overwrite=True)
    assert len((run / "metrics.csv").read_text().splitlines()) == 1 + 3  # until it learns
    model.learn(2)
    assert json.loads((run / "config.json").read_text())["run"]["task"] == "circle-3"
    assert len((run / "metrics.csv").read_text().splitlines()) == 1 + 2


def test_a_run_is_loaded_on_its_task_at_its_own_horizon_alone(tmp_path):
    """Its networks and stored interactions are that long: said in those words, not as a
    shape error."""
    run = tmp_path / "run"
    SILI("circle-3", method="sac", settings=FAST_AGENT, run_dir=run).learn(1)
    with pytest.raises(ConfigError, match=r"^env horizon=10: the run in .* with horizon 50, and"):
        SILI.load(run, env=make_task("circle-3", horizon=10))
    assert SILI.load(run, env=make_task("circle-3", horizon=50)).cfg.env_kwargs == {}


def test_loading_a_run_with_a_task_instance_of_other_sizes_names_both(tmp_path):
    run = tmp_path / "doors"
    SILI(TwoDoorsEnv(horizon=8), method="sili", settings=FAST_AGENT, run_dir=run).learn(2)
    assert SILI.load(run, env=TwoDoorsEnv(horizon=8)).predict([0.5, 0.0]).shape == (1,)
    with pytest.raises(ConfigError, match=r"^env horizon=5: the run in .* with horizon 8, and"):
        SILI.load(run, env=TwoDoorsEnv(horizon=5))  # 5 steps where 8 are stored: said first
    default = tmp_path / "default"  # its horizon unrecorded: the sizes tell
    SILI(TwoDoorsEnv(), method="sili", settings=FAST_AGENT, run_dir=default).learn(2)
    with pytest.raises(ConfigError, match=r"env does not fit the run in .* with \{\}; env is") as e:
        SILI.load(default, env=TwoDoorsEnv(horizon=5))
    assert "{'horizon': 5} (horizon 5, observations (2,), actions (1,)): give the task" in str(
        e.value
    )
    assert f"if it has them, {default / 'checkpoint.pt'} is another run's" in str(e.value)


def test_a_task_given_by_any_name_is_recorded_by_its_name(tmp_path):
    import gymnasium as gym

    by_id = SILI("sili/Circle3-v1", method="sac", settings=FAST_AGENT, run_dir=tmp_path / "a")
    by_env = SILI(gym.make("sili/Circle3-v0"), method="sac", settings=FAST_AGENT)
    assert (by_id.cfg.task, by_id.cfg.task_id) == ("circle-3", "sili/Circle3-v1")
    assert (by_env.cfg.task, by_env.cfg.task_id) == ("circle-3-v0", "sili/Circle3-v0")
    with pytest.raises(ConfigError, match=r"seed -1 is not allowed: give an integer in \[0, "):
        SILI("circle-3", method="sac", seed=-1)
    seeded = SILI("circle-3", method="sac", seed=np.int64(3), settings=FAST_AGENT)
    assert type(seeded.cfg.seed) is int and seeded.cfg.seed == 3  # recorded as JSON can


def test_a_packaged_task_given_as_its_class_is_warned_about_and_a_version_is_not(tmp_path, capsys):
    """CircleEnv has the class's defaults and no version on record: as an instance, a class
    path or the CLI's --task/--tasks, the user is told which names build a version; a version
    by name, and a user's own class, train quietly."""
    import warnings

    import gymnasium as gym

    from sili_robots.tasks.circle import CircleEnv

    told = "CircleEnv built from its class trains with the class's own defaults, which need not "
    names = "make_task(NAME): circle-3, circle-8, circle-continuous, circle-unequal"
    path = "sili_robots.tasks.circle:CircleEnv"
    for task in (CircleEnv(variant="3"), path):
        with pytest.warns(UserWarning, match=f"^{re.escape(told)}.*{re.escape(names)}$"):
            SILI(task, method="sac", settings=FAST_AGENT)
    with warnings.catch_warnings():
        warnings.simplefilter("error", UserWarning)
        warnings.simplefilter("ignore", UnreadSettingWarning)  # FAST_AGENT's latent settings
        SILI(make_task("circle-3"), method="sac", settings=FAST_AGENT)
        SILI(gym.make("sili/Circle3-v0"), method="sac", settings=FAST_AGENT)
        SILI(TwoDoorsEnv(horizon=6), method="sac", settings=FAST_AGENT)
        SILI(TWO_DOORS, method="sac", settings=FAST_AGENT)
    sweep = ["sweep", "--methods", "sac", "--seeds", "0", "--dry-run", "--out"]
    assert main([*sweep, str(tmp_path / "s"), "--tasks", f"{path},circle-3"]) == 0
    err = capsys.readouterr().err
    assert err.count("note:") == 1 and f"sili sweep: note: {told}" in err and names in err
    assert main([*sweep, str(tmp_path / "t"), "--tasks", f"{TWO_DOORS},circle-3"]) == 0
    assert "note:" not in capsys.readouterr().err
    train = ["train", "--task", path, "--method", "sac", "--interactions", "1", "--no-progress"]
    assert main([*train, "--set", "hidden=8", "--out", str(tmp_path / "r")]) == 0
    assert f"sili train: note: {told}" in capsys.readouterr().err


def test_a_task_instance_is_recorded_with_its_arguments_and_rebuilt_with_them(tmp_path):
    import gymnasium as gym

    SILI(TwoDoorsEnv(horizon=6), method="sac", settings=FAST_AGENT, run_dir=tmp_path / "d").learn(2)
    loaded = SILI.load(tmp_path / "d")  # built again from config.json: the same horizon
    assert loaded.cfg.env_kwargs == {"horizon": 6} and loaded.env.unwrapped.horizon == 6
    assert loaded.evaluate(2)["interactions"] == 2
    made = SILI(gym.make("sili/Circle3-v1", outside_margin=0.3), method="sac", settings=FAST_AGENT)
    assert made.cfg.env_kwargs == {"outside_margin": 0.3}  # not the version's own arguments
    with pytest.raises(ConfigError, match=r"env_kwargs apply to a task built by name; this ins"):
        SILI(TwoDoorsEnv(horizon=6), env_kwargs={"horizon": 7})
    for built, said in (({"outside_margin": 0.3}, "{'outside_margin': 0.3}"), ({}, "its default")):
        with pytest.raises(ConfigError, match=f"this instance was built with {re.escape(said)}"):
            SILI(gym.make("sili/Circle3-v1", **built), env_kwargs={"near_moves": 2})  # not variant
    with pytest.raises(ConfigError, match=r"^env is wrapped in ClipAction, which a run cannot"):
        SILI(gym.wrappers.ClipAction(make_task("circle-3")), env_kwargs={"horizon": 7})
    numpy_horizon = SILI(TwoDoorsEnv(horizon=np.int64(6)), method="sac", settings=FAST_AGENT)
    assert type(numpy_horizon.cfg.env_kwargs["horizon"]) is int  # recorded as JSON can
    speaker = make_task("speaker-listener", speaker=np.array([0.3, -0.8]))
    assert SILI(speaker, method="sac").cfg.env_kwargs == {"speaker": [0.3, -0.8]}
    gym.register("test/Doors-v0", entry_point=TWO_DOORS, kwargs={"horizon": 7})
    try:  # a version registered elsewhere is rebuilt from its class: with all its arguments
        mine = SILI(gym.make("test/Doors-v0"), method="sac", settings=FAST_AGENT)
        assert (mine.cfg.task, mine.cfg.env_kwargs) == (TWO_DOORS, {"horizon": 7})
    finally:
        del gym.registry["test/Doors-v0"]

    class LabelledDoors(TwoDoorsEnv):
        def __init__(self, horizon: int = 20, label: object = None) -> None:
            super().__init__(horizon)

    with pytest.raises(ConfigError, match=r"task argument label=<object .* cannot be recorded"):
        SILI(LabelledDoors(label=object()))


def test_evaluate_plays_on_the_models_own_simulation_and_close_frees_it():
    """Driving holds libsumo's one simulation per process: evaluating a model whose ``env`` is
    open must not start a second, and ``close`` hands the simulation back."""
    model = SILI("driving", method="sac", settings=FAST_AGENT).learn(2)
    run_dir = model.run_dir
    model.env.reset()
    assert model.evaluate(2)["interactions"] == 2
    assert model.env.action_space.contains(model.predict(model.env.reset()[0]))
    model.close()
    other = SILI("driving", method="sac", settings=FAST_AGENT)
    other.env.reset()  # SUMO starts here: the process's one simulation is free again
    other.close()
    del model
    gc.collect()
    assert not run_dir.exists()  # a temporary run goes with its model


def test_save_replaces_its_own_saves_and_another_run_only_with_overwrite(tmp_path):
    model = SILI("circle-3", method="sac", settings=FAST_AGENT).learn(1)
    target = tmp_path / "saved"
    target.mkdir()
    (target / "metrics.csv.gz").write_text("")  # of an earlier run
    with pytest.raises(ConfigError, match=r"holds a run's files .* save\(path, overwrite=True\)"):
        model.save(target)
    model.save(target, overwrite=True)
    saved = sorted(p.name for p in target.iterdir())
    assert saved == sorted(p.name for p in model.run_dir.iterdir())  # no metrics.csv.gz
    model.learn(1).save(target)  # its own earlier save: replaced, as stable-baselines3's
    assert SILI.load(target).cfg.interactions == 2
    other = SILI("circle-3", method="sac", seed=1, settings=FAST_AGENT).learn(1)
    with pytest.raises(ConfigError, match=r"already holds a run; SILI.load\(.*\) continues it"):
        other.save(target)  # another model's run is never replaced unasked
    assert SILI.load(target).cfg.interactions == 2
    other.save(target, overwrite=True)
    assert SILI.load(target).cfg.seed == 1
    with pytest.raises(ConfigError, match="already holds a run"):
        model.save(target)  # no longer what this model left there
    SILI.load(target).learn(1)  # trained on where it lies: not the other's save any more
    with pytest.raises(ConfigError, match="already holds a run"):
        other.save(target)
    (tmp_path / "file").write_text("")
    with pytest.raises(ConfigError, match=r"cannot save to .*file: it is a file; give a directory"):
        model.save(tmp_path / "file")
    for refused in (model, other):  # (kept by the refusals: see the next test)
        shutil.rmtree(refused.run_dir)


def test_a_refused_save_keeps_the_training_and_says_where(tmp_path):
    """A script whose save is refused ends there: its temporary run must outlive the model."""
    taken = tmp_path / "taken"
    SILI("circle-3", method="sac", settings=FAST_AGENT).learn(1).save(taken)
    model = SILI("circle-3", method="sac", seed=1, settings=FAST_AGENT).learn(1)
    run_dir = model.run_dir
    kept = rf"already holds a run.*; the model's training is kept in {re.escape(str(run_dir))} "
    with pytest.raises(ConfigError, match=kept + r"\(SILI.load\(.*\) continues it\)"):
        model.save(taken)
    del model
    gc.collect()
    assert SILI.load(run_dir).cfg.seed == 1
    shutil.rmtree(run_dir)
    model = SILI("circle-3", method="sac", seed=2, settings=FAST_AGENT).learn(1)
    run_dir = model.run_dir
    for _ in range(2):  # refused again, it says so again
        with pytest.raises(ConfigError, match="training is kept in"):
            model.save(taken)
    model.save(tmp_path / "elsewhere")  # saved after all: the temporary run goes with the model
    del model
    gc.collect()
    assert not run_dir.exists() and SILI.load(tmp_path / "elsewhere").cfg.seed == 2
    model = SILI("circle-3", method="sac", seed=3, settings=FAST_AGENT).learn(1)
    with pytest.raises(ConfigError, match="training is kept in"):
        model.save(taken)
    run_dir, loaded = model.run_dir, SILI.load(model.run_dir)  # as the refusal says
    model.save(tmp_path / "third")
    del model
    gc.collect()
    assert loaded.learn(1).cfg.interactions == 2  # its folder stays: the loaded model's now
    shutil.rmtree(run_dir)


class BytesPath:
    """A path-like whose path is bytes, which pathlib refuses with a TypeError."""

    def __fspath__(self) -> bytes:
        return b"run"

    def __repr__(self) -> str:
        return "<BytesPath>"


class BlankPath:
    """A path-like whose path is blank, which pathlib takes as the current directory."""

    def __fspath__(self) -> str:
        return ""


def test_a_path_that_is_not_one_is_refused_and_a_refused_save_keeps_the_training(tmp_path):
    for bad in (5, b"run", ""):  # None is a temporary run
        with pytest.raises(ConfigError, match=r"run_dir (must be a path|'' is not a usable)"):
            SILI("circle-3", method="sac", settings=FAST_AGENT, run_dir=bad)
    for bad in (5, None, b"run"):
        with pytest.raises(ConfigError, match=re.escape("path must be a path (a string or")):
            SILI.load(bad)
    model = SILI("circle-3", method="sac", seed=1, settings=FAST_AGENT).learn(1)
    run_dir = model.run_dir
    for bad, why in [
        (None, "save path must be a path (a string or pathlib.Path), got None"),
        (5, "save path must be a path (a string or pathlib.Path), got 5"),
        (str(tmp_path / "x\0y"), "is not a usable path (empty, blank or with a NUL byte)"),
        ("", "save path '' is not a usable path"),
        ("  ", "save path '  ' is not a usable path (empty, blank"),
        (BytesPath(), "save path must be a path (a string or pathlib.Path), got <BytesPath>"),
        (BlankPath(), "save path '' is not a usable path (empty, blank"),
    ]:
        with pytest.raises(ConfigError, match=re.escape(why) + ".*training is kept in"):
            model.save(bad)
    del model
    gc.collect()
    assert SILI.load(run_dir).cfg.seed == 1  # the script's training outlived the model
    shutil.rmtree(run_dir)


def test_a_task_module_in_the_current_directory_trains_and_a_scripts_class_is_explained(
    tmp_path, monkeypatch, capsys
):
    """A console script does not search the current directory as ``python -m`` does; a task's
    module there is found all the same."""
    monkeypatch.setattr(sys, "path", list(sys.path))
    monkeypatch.chdir(tmp_path)
    (tmp_path / "mydoors.py").write_text(
        "from sili_robots.examples.two_doors import TwoDoorsEnv\n\n\n"
        "class Doors(TwoDoorsEnv):\n    pass\n"
    )
    args = ["train", "--task", "mydoors:Doors", "--method", "sac", "--interactions", "2"]
    fast = [x for k, v in FAST_AGENT.items() for x in ("--set", f"{k}={v}")]
    assert main([*args, *fast, "--out", "run", "--no-progress"]) == 0
    assert json.loads((tmp_path / "run" / "config.json").read_text())["run"]["task"] == (
        "mydoors:Doors"
    )
    with pytest.raises(ConfigError, match=r"a class defined in a script loads only in that scr"):
        task_class("__main__:Doors")


def test_a_temporary_run_stays_when_saved_or_loaded_where_it_is():
    kept = []
    for keep in (lambda m: m.save(m.run_dir), lambda m: SILI.load(m.run_dir)):
        model = SILI("circle-3", method="sac", settings=FAST_AGENT).learn(1)
        run_dir, still_used = model.run_dir, keep(model)
        del model
        gc.collect()
        assert (run_dir / "checkpoint.pt").is_file(), still_used
        kept.append(run_dir)
    for run_dir in kept:
        shutil.rmtree(run_dir)


def test_the_two_doors_example_moves_the_door_as_its_rule_says():
    """The README's template task: ending near the middle switches the door, at a door keeps it."""
    env = TwoDoorsEnv(horizon=6)
    _, info = env.reset(seed=0)
    door = env.door
    for _ in range(6):
        env.step(np.zeros(1, np.float32))  # stays at x = 0: near the middle
    _, info = env.reset()
    assert env.door == -door and info["strategy_changed"] and info["strategy_id"] == -door
    for _ in range(6):
        env.step(np.array([env.door], np.float32))  # to the door: |x| reaches 1
    _, info = env.reset()
    assert env.door == -door and not info["strategy_changed"]


def test_learn_stopped_by_ctrl_c_leaves_the_model_at_its_checkpoint_and_counts_on_from_it(
    tmp_path, monkeypatch
):
    """As a stable-baselines3 model after Ctrl-C: what was learned stays in the model, and the
    next ``learn(n)`` trains n more (not up to the stopped learn's target)."""
    import signal

    from sili_robots import training

    played, calls = training.play_interaction, []

    def ctrl_c_in_the_fourth(*args, **kwargs):
        calls.append(1)
        if len(calls) == 4:
            signal.raise_signal(signal.SIGINT)
        return played(*args, **kwargs)

    monkeypatch.setattr(training, "play_interaction", ctrl_c_in_the_fourth)
    run = tmp_path / "run"
    model = SILI("circle-3", method="sac", settings=FAST_AGENT, run_dir=run, checkpoint_every=50)
    # as at a terminal: a background job (e.g. a CI runner's) starts with SIGINT ignored
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        with pytest.raises(KeyboardInterrupt):
            model.learn(2000)
    finally:
        signal.signal(signal.SIGINT, previous)
    assert model.agent.buffer.n == 4  # the checkpoint's agent, not the untrained one
    assert model.trained_interactions == 4 and model.config.interactions == 2000
    model.learn(2)
    assert model.trained_interactions == 6
    assert len((run / "metrics.csv").read_text().splitlines()) == 1 + 6
    assert model.agent.buffer.n == 6 and SILI.load(run).cfg.interactions == 6


def test_ctrl_c_while_learn_takes_back_its_checkpoint_acts_once_the_model_has_it(
    tmp_path, monkeypatch
):
    """A second press of the stop can fall in learn's last step: it left a new model beside
    its trained run (the next learn refused: "already holds a run"), or a trained one before
    its training."""
    import signal

    reload = SILI._reload

    def pressed_meanwhile(self):
        signal.raise_signal(signal.SIGINT)
        reload(self)

    run = tmp_path / "run"
    model = SILI("circle-3", method="sac", settings=FAST_AGENT, run_dir=run)
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)  # as at a terminal
    try:
        for interactions in (2, 5):
            with monkeypatch.context() as patch:
                patch.setattr(SILI, "_reload", pressed_meanwhile)
                with pytest.raises(KeyboardInterrupt):
                    model.learn(interactions - model.agent.buffer.n)
            assert model.agent.buffer.n == interactions  # the checkpoint's agent
    finally:
        signal.signal(signal.SIGINT, previous)
    model.learn(1)
    assert model.agent.buffer.n == 6


def test_save_copies_the_history_its_checkpoint_has_trained(tmp_path):
    run = tmp_path / "run"
    model = SILI("circle-3", method="sac", settings=FAST_AGENT, run_dir=run).learn(3)
    with (run / "metrics.csv").open("a") as f:  # a row a stop wrote after the checkpoint
        f.write((run / "metrics.csv").read_text().splitlines()[-1] + "\n")
    model.save(tmp_path / "saved")
    saved = (tmp_path / "saved" / "metrics.csv").read_text().splitlines()
    assert saved == (run / "metrics.csv").read_text().splitlines()[: 1 + 3]


def test_a_kept_history_counts_records_not_lines(tmp_path):
    from sili_robots.metrics import MetricsWriter

    writer = MetricsWriter(tmp_path, ("interaction", "note"))
    for j, note in enumerate(["line1\nline2", "b", "c"]):  # an add-on's text with a newline
        writer.write({"interaction": j, "note": note})
    writer.close()
    MetricsWriter(tmp_path, ("interaction", "note"), keep_rows=2).close()  # as save keeps it
    with (tmp_path / "metrics.csv").open(newline="") as f:
        assert [r["note"] for r in csv.DictReader(f)] == ["line1\nline2", "b"]


def test_predict_refuses_a_non_finite_observation_and_the_agent_another_default_dtype():
    import torch

    model = SILI("circle-3", method="sac", settings=FAST_AGENT)
    with pytest.raises(ConfigError, match=r"obs \[nan  0.  0.\] is not finite"):
        model.predict(np.array([np.nan, 0.0, 0.0]))
    torch.set_default_dtype(torch.float64)
    try:
        with pytest.raises(ConfigError, match=r"default dtype is torch.float64 .*torch.float32"):
            SILI("circle-3", method="sac", settings=FAST_AGENT)
    finally:
        torch.set_default_dtype(torch.float32)


def test_a_run_dir_that_cannot_be_made_is_named_before_the_model_changes(tmp_path, monkeypatch):
    (tmp_path / "file").write_text("not a folder")
    model = SILI("circle-3", method="sac", settings=FAST_AGENT, run_dir=tmp_path / "file" / "run")
    closed = []  # Circle's close frees nothing, so its calls are counted
    monkeypatch.setattr(model.env.unwrapped, "close", lambda: closed.append(1))
    with pytest.raises(ConfigError, match=r"cannot create the run directory .*; give run_dir a"):
        model.learn(1)
    assert closed == []  # still the model it was: its task is open
    obs, _ = model.env.reset(seed=0)
    assert model.predict(obs).shape == (2,)


def test_learn_failing_before_its_first_checkpoint_leaves_a_new_model(tmp_path, monkeypatch):
    from sili_robots import training

    def failing(*args, **kwargs):
        raise RuntimeError("the simulator fell over")

    run = tmp_path / "run"
    model = SILI("circle-3", method="sac", settings=FAST_AGENT, run_dir=run)
    with monkeypatch.context() as patch:
        patch.setattr(training, "play_interaction", failing)
        with pytest.raises(RuntimeError, match="fell over"):
            model.learn(5)
    assert not (run / "config.json").exists()  # nothing of the failed start
    model.learn(2)  # not refused as a run already there
    assert len((run / "metrics.csv").read_text().splitlines()) == 1 + 2


def test_two_models_of_one_run_each_count_from_the_run_as_it_is(tmp_path):
    run = tmp_path / "run"
    SILI("circle-3", method="sac", settings=FAST_AGENT, run_dir=run).learn(2)
    a, b = SILI.load(run), SILI.load(run)
    a.learn(2)
    b.learn(2)  # not "already at 4": b catches up with a's training first
    assert len((run / "metrics.csv").read_text().splitlines()) == 1 + 6
    assert b.agent.buffer.n == 6 and b.cfg.interactions == 6


def test_reading_a_models_count_changes_neither_it_nor_the_game_played_on_it(tmp_path):
    """Read after another model trained the run, ``trained_interactions`` reloaded the agent
    and reset the interaction being played on ``model.env``; ``learn`` still catches up."""
    run = tmp_path / "run"
    SILI("circle-3", method="sac", settings=FAST_AGENT, run_dir=run).learn(2)
    a, b = SILI.load(run), SILI.load(run)
    obs, _ = a.env.reset()
    obs, *_ = a.env.step(a.predict(obs))
    agent = a.agent
    b.learn(1)
    assert a.trained_interactions == 2 and a.agent is agent  # the model it predicts with
    a.env.step(a.predict(obs))  # the interaction goes on
    a.learn(1)
    assert a.trained_interactions == 4 and a.agent.buffer.n == 4


def test_a_model_whose_run_was_replaced_refuses_to_go_on_as_the_new_one(tmp_path):
    """``overwrite=True`` made another run in the folder: the first model became the new SAC
    run at its fewer interactions, without a word."""
    run = tmp_path / "run"
    first = SILI("circle-3", method="sili", settings=FAST_AGENT, run_dir=run).learn(3)
    SILI("circle-3", method="sac", settings=FAST_AGENT, run_dir=run, overwrite=True).learn(2)
    replaced = f"the run in {run} was replaced since this model loaded it (2 trained, not 3 or "
    replaced += "more; method 'sac', not 'sili'; "
    for use in (lambda: first.learn(1), lambda: first.save(tmp_path / "s"), first.evaluate):
        with pytest.raises(ConfigError, match=re.escape(replaced)) as refused:
            use()
        assert str(refused.value).endswith(f"; ...): SILI.load('{run}') takes up the new one")
    assert first.config.method == "sili" and first.trained_interactions == 3
    again = SILI("circle-3", method="sac", settings=FAST_AGENT, run_dir=run, overwrite=True)
    again.learn(3)  # the same settings again, anew: fewer interactions than the model held
    other = SILI.load(run)
    SILI("circle-3", method="sac", settings=FAST_AGENT, run_dir=run, overwrite=True).learn(1)
    with pytest.raises(
        ConfigError, match=r"replaced since this model loaded it \(1 trained, not 3 or more\)"
    ):
        other.learn(1)
    model = SILI.load(run)  # its kernels changed for another machine: the same run goes on
    record = json.loads((run / "config.json").read_text())
    record["run"]["agent"]["matmul"] = "aten" if model.cfg.agent.matmul != "aten" else "onednn"
    record["run"]["threads"] = 2
    (run / "config.json").write_text(json.dumps(record))
    model.learn(1)
    assert model.trained_interactions == 2


def test_a_config_changed_by_hand_is_refused_not_used_or_dropped_by_chance(tmp_path):
    """Before the first ``learn`` an edit of ``model.config`` was trained with (the agent
    predicting before it was built without it); after it, dropped at the next reload."""
    fresh = SILI("circle-3", method="sac", settings=FAST_AGENT, run_dir=tmp_path / "a")
    fresh.config.agent.hidden += 1
    hidden = fresh.config.agent.hidden
    with pytest.raises(
        ConfigError, match=rf"changed .* \(agent.hidden {hidden}, not {hidden - 1}\)"
    ):
        fresh.learn(1)
    assert not (tmp_path / "a" / "config.json").exists()
    trained = SILI("circle-3", method="sac", settings=FAST_AGENT, run_dir=tmp_path / "b").learn(1)
    trained.config.agent.sac.lr = 0.5
    with pytest.raises(ConfigError, match=r"\(agent.sac.lr 0.5, not 0.0003\): a model's settings"):
        trained.learn(1)
    trained.config.agent.sac.lr = 0.0003  # as it was: trains on
    assert trained.learn(1).trained_interactions == 2


def test_a_model_is_not_saved_inside_its_own_run(tmp_path):
    """A save into a temporary run's folder was removed with the model."""
    model = SILI("circle-3", method="sac", settings=FAST_AGENT).learn(1)
    inside = model.run_dir / "backup"
    with pytest.raises(ConfigError, match=re.escape(f"{inside}: it is inside the model's own")):
        model.save(inside)
    assert not inside.exists()


def test_what_a_run_cannot_record_or_train_on_is_refused(tmp_path):
    import gymnasium as gym

    from sili_robots.wrappers import OracleObservation

    task = gym.make("sili/Circle3-v1")
    scaled = gym.wrappers.TransformObservation(task, lambda o: o * 100, task.observation_space)
    with pytest.raises(ConfigError, match="env is wrapped in TransformObservation, which a run"):
        SILI(scaled, method="sac")
    with pytest.raises(ConfigError, match="env is wrapped in OracleObservation"):
        SILI(OracleObservation(task.unwrapped), method="oracle")  # the method adds its own
    with pytest.raises(ConfigError, match=r"TimeLimit, .* built with horizon=N for interactions"):
        SILI(gym.make("sili/Circle3-v1", max_episode_steps=30), method="sac")
    run = tmp_path / "run"
    SILI(task, method="sac", settings=FAST_AGENT, run_dir=run).learn(2)
    with pytest.raises(ConfigError, match=r"env is sili/Circle8-v1; the run in .* was trained on"):
        SILI.load(run, env=gym.make("sili/Circle8-v1"))  # same sizes, another game
    other = SILI.load(run, env=gym.make("sili/Circle3-v1", outside_margin=0.3))
    assert other.predict(other.env.reset()[0]).shape == (2,)  # plays it
    with pytest.raises(ConfigError, match=r"built with \{'outside_margin': 0.3\}, can play it but"):
        other.learn(1)
    assert len((run / "metrics.csv").read_text().splitlines()) == 1 + 2


def test_a_sawyer_run_played_with_another_controller_names_its_own_when_it_refuses_to_train(
    tmp_path,
):
    """As ``sili eval``'s ``trained_with``: the controller the run used, given or not."""
    run = tmp_path / "run"
    SILI("sawyer-reach", method="sac", settings=FAST_AGENT, run_dir=run).learn(1)
    other = SILI.load(run, env=make_task("sawyer-reach", controller="joint_velocity"))
    try:
        with pytest.raises(ConfigError, match=r"was trained with \{'controller': 'mink'\}; env"):
            other.learn(1)
    finally:
        other.close()


def test_predict_env_and_learn_as_a_user_of_numpy_and_torch_expects(tmp_path):
    import torch

    torch.set_num_threads(2)
    run = tmp_path / "run"
    model = SILI("circle-3", method="sac", settings=FAST_AGENT, run_dir=run).learn(np.int64(3))
    assert torch.get_num_threads() == 2  # the caller's, back after training on the run's one
    obs, info = model.env.reset()  # the game the run trained in goes on
    assert info["interaction"] == 3
    with pytest.raises(ConfigError, match="obs is a batch of 4; predict takes one observation"):
        model.predict(np.stack([obs] * 4))
    for bad in ("abc", [obs[0], "x"], {"obs": obs}):
        with pytest.raises(ConfigError, match=r"obs .* is not an array of numbers"):
            model.predict(bad)
    made = torch.tensor(obs, dtype=torch.float64, requires_grad=True) * 1.0  # a graph's output
    np.testing.assert_array_equal(model.predict(made), model.predict(obs))
    half = torch.tensor(obs, dtype=torch.bfloat16)  # numbers numpy has no type for
    np.testing.assert_array_equal(model.predict(half), model.predict(half.float().numpy()))
    for first in ({"restart": False}, None):  # asks for no other game: the trained one goes on
        model = SILI.load(run)
        with pytest.raises(ConfigError, match="unknown strategy 99"):
            model.env.reset(options={"strategy": 99})  # refused: the game is as it was
        with pytest.raises(ConfigError, match=r"unknown reset options \['Strategy'\]"):
            model.env.reset(options={"Strategy": 0})  # a slip, not the old game unasked
        with pytest.raises(ConfigError, match=r"reset options must be a dict .*, got str"):
            model.env.reset(options="restart")  # the task's own refusal, not AttributeError
        assert model.env.reset(options=first)[1]["interaction"] == 3
    model = SILI.load(run)
    obs, info = model.env.reset(seed=5, options={"strategy": 0})  # another game, as asked
    assert (info["interaction"], info["strategy_id"]) == (0, 0)


def test_a_model_never_removes_its_run_and_never_trains_beside_another_process(tmp_path):
    import os
    import socket
    import subprocess

    run = tmp_path / "run"
    SILI("circle-3", method="sac", settings=FAST_AGENT, run_dir=run).learn(2)
    model = SILI.load(run)
    (run / "checkpoint.pt").unlink()  # a run kept without its checkpoint
    with pytest.raises(ConfigError, match="checkpoint"):
        model.save(tmp_path / "copy")
    assert {"config.json", "metrics.csv", "summary.json"} <= {p.name for p in run.iterdir()}
    gone = SILI("circle-3", method="sac", settings=FAST_AGENT, run_dir=tmp_path / "gone")
    gone.learn(2)
    shutil.rmtree(gone.run_dir)
    with pytest.raises(ConfigError):
        gone.learn(2)  # not a new run in its place
    assert not gone.run_dir.exists()
    busy = SILI("circle-3", method="sac", settings=FAST_AGENT, run_dir=tmp_path / "busy").learn(1)
    other = subprocess.Popen(["sleep", "60"])
    try:  # as `sili train --resume` or a sweep's worker marks the run it trains
        host = socket.gethostname()
        (busy.run_dir / "worker.json").write_text(json.dumps({"pid": other.pid, "host": host}))
        with pytest.raises(ConfigError, match=f"being trained by process {other.pid}"):
            busy.learn(1)
        anew = SILI("circle-3", settings=FAST_AGENT, run_dir=busy.run_dir, overwrite=True)
        with pytest.raises(ConfigError, match=f"being trained by process {other.pid}"):
            anew.learn(1)  # not cleared from under it
    finally:
        other.kill()
        other.wait()
    assert os.getpid() != other.pid and len(SILI.load(busy.run_dir).agent.Z) == 1 + 1


def test_load_takes_the_task_a_script_defined_and_an_instance_built_at_its_defaults(tmp_path):
    import gymnasium as gym

    run = tmp_path / "run"
    SILI(TwoDoorsEnv(horizon=6), method="sac", settings=FAST_AGENT, run_dir=run).learn(2)
    record = json.loads((run / "config.json").read_text())
    record["run"]["task"], record["run"]["task_id"] = "__main__:TwoDoorsEnv", None
    (run / "config.json").write_text(json.dumps(record))  # as a script defining the class does
    assert SILI.load(run, env=TwoDoorsEnv(horizon=6)).learn(1).cfg.interactions == 3
    circle = tmp_path / "circle"
    SILI("circle-3", method="sac", settings=FAST_AGENT, run_dir=circle).learn(1)
    same = SILI.load(circle, env=gym.make("sili/Circle3-v1", horizon=50))  # the default
    assert same.learn(1).cfg.interactions == 2


def test_a_refused_load_leaves_a_temporary_run_to_its_model():
    import gymnasium as gym

    model = SILI("circle-3", method="sac", settings=FAST_AGENT).learn(1)
    with pytest.raises(ConfigError, match="env is sili/Circle8-v1"):
        SILI.load(model.run_dir, env=gym.make("sili/Circle8-v1"))
    run_dir = model.run_dir
    del model
    gc.collect()
    assert not run_dir.exists()


def test_learn_marks_the_run_it_trains_also_when_it_replaces_one(tmp_path, monkeypatch):
    from sili_robots import training

    played, claimed = training.play_interaction, []

    def noting_the_claim(*args, **kwargs):
        claimed.append((tmp_path / "run" / "worker.json").is_file())
        return played(*args, **kwargs)

    SILI("circle-3", method="sac", settings=FAST_AGENT, run_dir=tmp_path / "run").learn(1)
    monkeypatch.setattr(training, "play_interaction", noting_the_claim)
    SILI("circle-3", settings=FAST_AGENT, run_dir=tmp_path / "run", overwrite=True).learn(2)
    assert claimed == [True, True]  # a sweep or `sili train --resume` would refuse the run
    assert not (tmp_path / "run" / "worker.json").exists()  # and it is given back


def test_another_game_on_model_env_starts_the_agent_with_no_history(tmp_path):
    """The latents carried over from the trained game are not the history of a restarted one:
    the true-latent mode acts on the new game's strategy, SILI on "no history" (as in a run's
    first interaction), and the interaction before the restart is not fed to the agent."""

    def play_one(model: SILI, obs: np.ndarray) -> None:
        for _ in range(model.env.unwrapped.horizon):
            obs = model.env.step(model.predict(obs))[0]

    true = tmp_path / "true"
    SILI("circle-3", method="sili", latent="true", settings=FAST_AGENT, run_dir=true).learn(2)
    for strategy in range(3):  # the trained game's next strategy is one of them
        model = SILI.load(true)
        obs, info = model.env.reset(options={"strategy": strategy})
        z = model.agent.policy_input(obs)[len(obs) :]
        np.testing.assert_array_equal(z, np.concatenate([info["strategy"], [0, 0]]))
    model = SILI("circle-3", method="sili", settings=FAST_AGENT, run_dir=tmp_path / "s").learn(2)
    play_one(model, model.env.reset()[0])  # the trained game goes on
    obs, _ = model.env.reset()  # interaction 2 fed: z^3 inferred from it
    assert model.agent.buffer.n == 3 and np.abs(model.agent.policy_input(obs)[len(obs) :]).sum()
    play_one(model, obs)
    obs, info = model.env.reset(seed=7)  # a seed after the first reset: another game
    assert info["interaction"] == 0 and model.agent.buffer.n == 3
    np.testing.assert_array_equal(model.agent.policy_input(obs)[len(obs) :], 0.0)


def test_an_interaction_cut_short_on_model_env_is_named_not_silently_left_out(tmp_path):
    """Under a ``TimeLimit`` the agent's latent stayed frozen without a word: only whole
    interactions are encoded. Said once per ``model.env``, and only where a latent is acted on
    and an interaction was played."""
    import gymnasium as gym

    from sili_robots.errors import CutInteractionWarning

    def play(env: gym.Env, model: SILI, steps: int | None = None) -> None:
        obs, _ = env.reset()
        for _ in range(steps or model.env.unwrapped.horizon):
            obs, *_, truncated, _ = env.step(model.predict(obs))
            if truncated:
                break

    model = SILI("circle-3", method="sili", settings=FAST_AGENT, run_dir=tmp_path / "s").learn(2)
    cut = gym.wrappers.TimeLimit(model.env, 5)
    play(cut, model)
    with pytest.warns(CutInteractionWarning, match=r"ended after 5 of its 50 steps .* does not f"):
        play(cut, model)  # its reset ends the cut one
    assert model.agent.buffer.n == 2  # not fed
    with warnings.catch_warnings():
        warnings.simplefilter("error", CutInteractionWarning)
        for _ in range(2):
            play(cut, model)  # told once
        play(model.env, model)  # the next reset ends the cut one: not told again
        play(model.env, model)  # a whole one fed
        assert model.agent.buffer.n == 3
        sac = SILI("circle-3", method="sac", settings=FAST_AGENT, run_dir=tmp_path / "sac")
        play(gym.wrappers.TimeLimit(sac.learn(2).env, 5), sac)
        play(sac.env, sac)  # SAC acts on no latent: nothing to tell
        again = SILI.load(tmp_path / "s")
        again.env.reset()
        again.env.reset()  # nothing played (gymnasium's check_env resets so): nothing to tell


def test_model_env_passes_gymnasiums_check_env_and_its_spec_makes_the_task():
    """Tools that remake an env from its spec (``check_env``, recorders) get the task: the
    wrapper holding the agent cannot be made from a spec."""
    from gymnasium.utils.env_checker import check_env

    model = SILI("circle-3", method="sili", seed=0, settings=FAST_AGENT)
    with pytest.warns(UserWarning, match="different from the unwrapped"):
        check_env(model.env, skip_render_check=True)
    made = model.env.spec.make()
    assert made.spec.id == "sili/Circle3-v1" and made.unwrapped is not model.env.unwrapped
    made.close()


def test_model_env_feeds_the_agent_the_action_the_task_applied(tmp_path):
    """The task clips an action outside its box (as gymnasium's ClipAction); the agent was fed
    the action as given, so it inferred z from actions that were never played."""
    model = SILI("circle-3", method="sili", settings=FAST_AGENT, run_dir=tmp_path / "r").learn(2)
    model.env.reset()
    for _ in range(model.env.unwrapped.horizon):
        model.env.step(np.array([5.0, -7.0]))
    model.env.reset()  # the interaction is fed
    assert model.agent.buffer.n == 3
    np.testing.assert_array_equal(model.agent.buffer.act[2], np.tile([1.0, -1.0], (50, 1)))


def test_evaluate_on_a_task_instance_refuses_another_task_as_load_does(tmp_path):
    """evaluation.evaluate restored a Circle (3 Goals) game into Circle (8 Goals) and returned
    its numbers; a task of other sizes raised numpy's or torch's error."""

    run = tmp_path / "run"
    SILI("circle-3", method="sac", settings=FAST_AGENT, run_dir=run).learn(2)
    for task, said in (
        (make_task("circle-8"), r"env is sili/Circle8-v1; the run in .* was trained on"),
        (make_task("circle-3", horizon=10), r"env horizon=10: the run in .* with horizon 50"),
        (make_task("speaker-listener"), r"env is sili/SpeakerListener-v1; the run in"),
    ):
        with pytest.raises(ConfigError, match=said):
            evaluate(run, 2, task)
        task.close()
    with pytest.raises(ConfigError, match="interactions must be an integer >= 1, got 0"):
        evaluate(run, 0)
    assert evaluate(run, 2, make_task("circle-3", outside_margin=0.3))["interactions"] == 2


def test_a_new_model_over_another_run_has_nothing_to_save_or_evaluate_before_it_learns(tmp_path):
    run = tmp_path / "run"
    SILI("sili/Circle3-v0", seed=0, settings=FAST_AGENT, run_dir=run).learn(3).close()
    model = SILI("sili/Circle3-v0", seed=1, settings=FAST_AGENT, run_dir=run, overwrite=True)
    with pytest.raises(ConfigError, match="nothing to save yet"):
        model.save(tmp_path / "copy")
    with pytest.raises(ConfigError, match="nothing to evaluate yet"):
        model.evaluate(1)
    assert not (tmp_path / "copy").exists()


def test_a_forked_childs_copy_of_a_model_leaves_its_temporary_run():
    """A forked worker's copy of the model goes away with the worker: the parent's temporary
    run folder stays, as the parent still trains in it."""
    import os

    from sili_robots import api

    model = SILI("sili/Circle3-v0", settings=FAST_AGENT)
    finalizer = api._TEMPORARY[model.run_dir.resolve()]
    pid = os.fork()
    if pid == 0:
        code = 1
        try:
            finalizer()
            code = 0
        finally:
            os._exit(code)
    assert os.waitstatus_to_exitcode(os.waitpid(pid, 0)[1]) == 0
    assert model.run_dir.is_dir()
    model.close()


def test_what_sili_takes_is_named_and_a_string_is_no_flag(tmp_path):
    """A string such as "no" counted as true: overwrite="no" replaced a trained run."""
    kept = SILI("circle-3", method="sac", settings=FAST_AGENT, run_dir=tmp_path / "kept").learn(2)
    for make, said in (
        (lambda: SILI(None), "env must be a task name or id .* got None"),
        (lambda: SILI(TwoDoorsEnv), r"got <class .*TwoDoorsEnv'> \(a class: give an instance"),
        (lambda: SILI("circle-3", settings=[("hidden", 16)]), "settings must be a dict of names"),
        (lambda: SILI("circle-3", env_kwargs="horizon"), "env_kwargs must be a dict of names"),
        (lambda: SILI("circle-3", latent="discrete", settings={"latent": "partial"}), "given twi"),
        (
            lambda: SILI("circle-3", settings=FAST_AGENT, run_dir=kept.run_dir, overwrite="no"),
            "overwrite must be True or False, got 'no'",
        ),
        (lambda: kept.save(tmp_path / "x", overwrite="no"), "overwrite must be True or False"),
        (lambda: kept.predict(kept.env.reset()), r"reset\(\)'s \(obs, info\) pair; give its obs"),
        (lambda: kept.predict(kept.env.reset()[0], deterministic="no"), "deterministic must be"),
        (lambda: kept.learn(1, progress_bar="yes"), "progress_bar must be True or False"),
        (lambda: SILI.load(kept.run_dir, env="circle-3"), "env must be a task instance"),
        (lambda: evaluate(kept.run_dir, 1, task_env="circle-3"), "task_env must be a task inst"),
        (lambda: evaluate(None, 1), "run_dir must be a run's folder, got None"),
    ):
        with pytest.raises(ConfigError, match=said):
            make()
    assert SILI.load(kept.run_dir).cfg.interactions == 2  # nothing replaced or trained


def test_numpy_numbers_are_settings_as_pythons_are():
    settings = {**FAST_AGENT, "sac.lr": np.float32(0.5), "hidden": np.int64(16)}
    cfg = SILI("circle-3", settings={**settings, "model.sample": np.bool_(True)}).cfg.agent
    assert (cfg.sac.lr, cfg.hidden, cfg.model.sample) == (0.5, 16, True)
    assert type(cfg.hidden) is int and type(cfg.model.sample) is bool  # as config.json keeps


def test_a_held_model_env_plays_the_trained_agent_and_evaluate_keeps_the_random_state(tmp_path):
    """``env = model.env`` before ``learn`` (stable-baselines3's ``get_env`` habit) fed its
    interactions to the untrained agent while ``predict`` acted with the trained one; and
    ``evaluate`` set torch's global random state to the checkpoint's, so a loop of stochastic
    trials and evaluations repeated one trial."""
    import torch

    model = SILI("circle-3", seed=0, settings=FAST_AGENT, run_dir=tmp_path / "run")
    env = model.env
    model.learn(4)
    assert env is model.env and env.agent is model.agent
    assert env.reset()[1]["interaction"] == 4  # the trained run's game goes on
    model.evaluate(2)
    assert env is model.env and env.agent is model.agent
    torch.manual_seed(123)
    expected = torch.rand(3)
    torch.manual_seed(123)
    model.evaluate(1)
    assert torch.equal(torch.rand(3), expected)
    SILI.load(model.run_dir).learn(1)  # trained further: evaluate first catches up with it
    torch.manual_seed(123)
    model.evaluate(1)
    assert torch.equal(torch.rand(3), expected)
    SILI.load(model.run_dir).learn(1)  # and so does save
    torch.manual_seed(123)
    model.save(tmp_path / "saved")
    assert torch.equal(torch.rand(3), expected)


def test_a_schedule_is_a_setting_in_the_command_lines_text_too():
    from sili_robots.agent.schedule import Schedule

    model = SILI("circle-3", settings={**FAST_AGENT, "sili.beta": "0:0, 300:0.5"})
    assert model.cfg.agent.sili.beta == Schedule(((0, 0.0), (300, 0.5)))
    with pytest.raises(ConfigError, match=r"setting sili.beta: 'x:1' is not INTERACTION:VALUE"):
        SILI("circle-3", settings={"sili.beta": "0:0,x:1"})
    with pytest.raises(ConfigError, match=r"sac.lr must be a number or a schedule .*, got 'fast'"):
        SILI("circle-3", settings={"sac.lr": "fast"})  # no schedule in it: a number's error


def test_evaluate_on_a_users_task_instance_does_not_close_it(tmp_path, monkeypatch):
    """Without it, the user's task (e.g. a SUMO simulation) was closed under them."""
    run = tmp_path / "run"
    SILI("circle-3", method="sac", settings=FAST_AGENT, run_dir=run).learn(2)
    task = make_task("circle-3")
    closed = []
    monkeypatch.setattr(task, "close", lambda: closed.append(True))
    assert evaluate(run, 2, task)["interactions"] == 2
    assert closed == []
    model = SILI.load(run, env=task)
    model.evaluate(2)
    assert closed == []


def test_predict_samples_when_not_deterministic(tmp_path):
    """Without it, deterministic=False was silently the greedy action (no exploration)."""
    model = SILI("circle-3", method="sac", settings=FAST_AGENT, run_dir=tmp_path / "r")
    obs, _ = model.env.reset()
    greedy = [model.predict(obs) for _ in range(4)]
    sampled = [model.predict(obs, deterministic=False) for _ in range(4)]
    assert all(np.array_equal(a, greedy[0]) for a in greedy)
    assert len({tuple(np.asarray(a).ravel()) for a in sampled}) > 1


def test_evaluate_acts_deterministically_and_leaves_the_latents_unrefreshed(tmp_path, monkeypatch):
    """No exploration, and the run's cached latents stay those it was trained with."""
    settings = {**FAST_AGENT, "model.refresh_every": 1}  # training refreshes after each one
    cfg = make_run_config("circle-3", "sili", 0, 2, settings=settings)
    training.train(cfg, tmp_path / "run", progress=False)
    asked, refreshes, refreshed = [], [], []
    act, observe = SILIAgent.act, SILIAgent.observe_interaction
    refresh = SILIAgent.refresh_latents

    def recorded(self, obs, deterministic=False):
        asked.append(deterministic)
        return act(self, obs, deterministic)

    def observed(self, *args, refresh=True):
        refreshes.append(refresh)
        return observe(self, *args, refresh=refresh)

    monkeypatch.setattr(SILIAgent, "act", recorded)
    monkeypatch.setattr(SILIAgent, "observe_interaction", observed)
    monkeypatch.setattr(
        SILIAgent, "refresh_latents", lambda self: refreshed.append(1) or refresh(self)
    )
    evaluate(tmp_path / "run", 3)
    assert asked and all(asked)
    # the first two are fed when the next begins (the last is never followed), none refreshed
    assert refreshes == [False, False] and not refreshed


def test_a_models_folders_stay_where_they_were_given_and_a_tilde_is_home(tmp_path, monkeypatch):
    """A notebook changes directory: a relative run_dir, load or save path is the folder it
    named when given; ``~`` is the home folder, as in the CLI's paths."""
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    (tmp_path / "a").mkdir()
    monkeypatch.chdir(tmp_path / "a")
    model = SILI("circle-3", method="sac", settings=FAST_AGENT, run_dir="rel").learn(1)
    saved = model.save("~/saved")
    assert saved == tmp_path / "home" / "saved" and (saved / "checkpoint.pt").is_file()
    monkeypatch.chdir(tmp_path)
    model.learn(1)  # trains the run in a/rel, not a new one in ./rel
    assert model.run_dir == tmp_path / "a" / "rel" and not (tmp_path / "rel").exists()
    assert model.trained_interactions == 2 and model.evaluate(1)["trained_interactions"] == 2
    loaded = SILI.load("a/rel")
    monkeypatch.chdir(tmp_path / "home")
    assert loaded.trained_interactions == 2 and loaded.run_dir == tmp_path / "a" / "rel"
    assert SILI.load("~/saved").trained_interactions == 1
    with pytest.raises(ConfigError, match="'~nobody-here' names no user with a home"):
        SILI("circle-3", run_dir="~nobody-here/run")


def test_a_seed_on_model_envs_first_reset_starts_another_game_and_a_new_models_is_its_training(
    tmp_path,
):
    """gymnasium's reset(seed=...) restarts the game on the first reset too (before, the first
    continued the trained game whatever its seed); a new model's first reset plays the game its
    training begins with (its seed's), as stable-baselines3 seeds ``model.env``."""
    run = tmp_path / "run"
    SILI("circle-unequal", method="sac", seed=4, settings=FAST_AGENT, run_dir=run).learn(4)
    firsts = [float(r["strategy_id"]) for r in csv.DictReader((run / "metrics.csv").open())]
    model = SILI.load(run)
    _, info = model.env.reset()
    assert info["interaction"] == 4  # the trained game goes on
    games = []
    for seed in (1, 2, 1):
        model = SILI.load(run)
        _, info = model.env.reset(seed=seed)
        assert info["interaction"] == 0 and model.agent.buffer.n == 4
        games.append(_strategies(model, info, 6))
        assert model.env.reset()[1]["interaction"] == 6  # the new game goes on, not the saved
    assert games[0] == games[2] != games[1]
    new = SILI("circle-unequal", method="sac", seed=0, settings=FAST_AGENT)
    assert _strategies(new, new.env.reset(seed=1)[1], 6) == games[0]  # its own seed given way
    for _ in range(2):  # the same seed: the same game, the one its training played
        new = SILI("circle-unequal", method="sac", seed=4, settings=FAST_AGENT)
        _, info = new.env.reset()
        assert _strategies(new, info, 4) == firsts
    others = {tuple(_strategies(SILI("circle-unequal", seed=s), None, 6)) for s in range(4)}
    assert len(others) > 1  # not one game whatever the seed


def _strategies(model: SILI, info: dict | None, interactions: int) -> list[float]:
    """The strategy of each of ``interactions`` interactions played on ``model.env`` from
    ``info`` (None: its first reset's), standing still."""
    if info is None:
        info = model.env.reset()[1]
    out = [float(info["strategy_id"])]
    still = np.zeros(model.env.action_space.shape, np.float32)
    for _ in range(interactions - 1):
        for _ in range(model.env.unwrapped.horizon):
            model.env.step(still)
        out.append(float(model.env.reset()[1]["strategy_id"]))
    return out


def test_the_api_says_what_the_command_line_notes_and_names_a_runs_files(tmp_path):
    """A setting the method never reads warns as ``sili train`` notes it; a schedule given in
    another shape names both shapes; a run's file given for its run names the run; a copy,
    which would share the run and its simulation, is refused; a model's run removed since is
    said to be gone, not untrained."""
    import copy

    unread = r"setting 'model\.dim' does nothing here: it learns no latent"
    with pytest.warns(UnreadSettingWarning, match=unread):
        SILI("circle-3", method="sac", settings={**FAST_AGENT, "model.dim": 4})
    with pytest.raises(ConfigError, match=r"sili\.beta must be a number or a schedule \(INTER"):
        SILI("circle-3", settings={"sili.beta": [(0, 0.0), (100, 0.5)]})
    model = SILI("circle-3", method="sac", settings=FAST_AGENT, run_dir=tmp_path / "r").learn(1)
    run = re.escape(str(tmp_path / "r"))
    with pytest.raises(
        ConfigError, match=f"checkpoint.pt is a file, not a run directory: give {run}$"
    ):
        SILI.load(tmp_path / "r" / "checkpoint.pt")
    for copied in (copy.copy, copy.deepcopy, pickle.dumps):  # unpickled, it shared the run
        with pytest.raises(TypeError, match=r"save it and SILI\.load the saved copy"):
            copied(model)
    shutil.rmtree(tmp_path / "r")
    with pytest.raises(ConfigError, match="r does not exist \\(any more\\): no run is there"):
        model.evaluate(1)


def test_a_learn_refused_by_a_file_in_the_run_dir_leaves_the_model_and_its_game(tmp_path):
    """Refused before anything changes: the agent and the interaction played on model.env
    stay (the check inside the training claim alone would rebuild them)."""
    run = tmp_path / "run"
    model = SILI("circle-3", method="sac", settings=FAST_AGENT, run_dir=run)
    agent, still = model.agent, np.zeros(2, np.float32)
    model.env.reset()
    model.env.step(still)
    run.mkdir()
    (run / "notes.txt").write_text("mine")
    with pytest.raises(ConfigError, match=r"notes\.txt"):
        model.learn(1)
    assert model.agent is agent
    assert model.env.step(still)[-1]["t"] == 2  # the interaction under way goes on


def test_a_run_made_in_the_folder_while_learn_starts_is_refused_and_kept(tmp_path, monkeypatch):
    """Another process's run, finished in the folder between the model's checks and its
    claim: refused, and its files stay (the model clears only a run of its own)."""
    from sili_robots import api

    other = tmp_path / "other"
    SILI("circle-3", method="sac", settings=FAST_AGENT, run_dir=other).learn(1)
    run = tmp_path / "run"
    model = SILI("circle-3", method="sac", settings=FAST_AGENT, run_dir=run)
    made = api.make_run_dir

    def meanwhile(path, out="--out"):
        made(path, out)
        for f in other.iterdir():
            if f.is_file():
                shutil.copy2(f, run / f.name)

    monkeypatch.setattr(api, "make_run_dir", meanwhile)
    with pytest.raises(ConfigError):
        model.learn(1)
    assert (run / "config.json").is_file() and (run / "checkpoint.pt").is_file()
