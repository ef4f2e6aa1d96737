"""A user's own add-on (``addons.plugins``): loaded from the working directory, run by the
agent, its metric columns written, kept through a resume and named when it cannot load."""

from __future__ import annotations

import csv
import hashlib
import json
import re
import sys
import textwrap

import pandas as pd
import pytest
from fast_settings import FAST_ARGS

from sili_robots.build import make_run_config
from sili_robots.cli import main
from sili_robots.errors import ConfigError

PLUGIN = '''
import types

import numpy as np
import torch
from sili_robots.agent import stability
from sili_robots.agent.addon import AgentAddon


class Constant(AgentAddon):
    """d = 0.37 for every change: R_stable = -0.37 whatever the latents."""

    metric_columns = ("stored",)

    def __init__(self):
        self.stored = 0

    def interaction_stored(self, j):
        self.stored += 1
        return {"stored": self.stored, "not_declared": 1.0, "task_reward": 999.0}

    def stability_distance(self, j):
        return np.full(len(j), 0.37)


class Configured(AgentAddon):
    def __init__(self, d):
        self.d = d


class Buggy(AgentAddon):
    def __init__(self):
        self.n = len(5)  # its own TypeError, not a question of arguments


class Renamed(Constant):
    metric_columns = ("count",)


class Usurper(Constant):
    metric_columns = ("task_reward",)


class Scalar(AgentAddon):
    def stability_distance(self, j):
        return 0.5  # not one per interaction j


class Seeded(Constant):
    metric_columns = ("seed",)  # results.csv's run identity would replace its values


class Letters(Constant):
    metric_columns = "score"  # a string, not a tuple of names


class Unnamed(Constant):
    metric_columns = ("",)


class Twin(AgentAddon):
    pass  # named "addon" as Constant is


class SameColumn(AgentAddon):
    name = "same"
    metric_columns = ("stored",)  # Constant's column: one would overwrite the other's values


class ScaledChange(AgentAddon):
    def stability_distance(self, j):
        return 2.0 * stability.change_after(self.agent.Z, j, self.agent.cfg.latent)


class NaN(AgentAddon):
    def stability_distance(self, j):
        return np.full(j.shape, np.nan)


class NoValues(AgentAddon):
    def interaction_stored(self, j):
        self.last = j  # returns None, not its columns' values


class Tensor(Constant):
    def interaction_stored(self, j):
        return {"stored": torch.tensor(0.5)}  # written as "tensor(0.5)"


class Flags(AgentAddon):
    name = "flags"
    metric_columns = ("odd", "seen", "half")

    def interaction_stored(self, j):
        return {"odd": bool(j % 2), "seen": np.bool_(True), "half": np.float32(j / 2)}


class ShortLatent(AgentAddon):
    def acting_latent(self):
        return np.zeros(3, np.float32)  # the latent has 10 entries


class PastTheEnd(AgentAddon):
    def latent_pairs(self, j):
        return j + self.agent.buffer.n  # rows not stored yet: the buffer's zeros, without a word


class AtTheEnd(AgentAddon):
    def rl_interactions(self, j):
        return np.full_like(j, self.agent.buffer.n)  # one past the last stored: a zero row


class NotAnAddon:
    pass


class BeforeTheFirst(AgentAddon):
    def rl_interactions(self, j):
        return (j - 1).tolist()  # -1 is numpy's last row, without a word


class Ragged(AgentAddon):
    def acting_latent(self):
        return [0.0, [1.0, 2.0]]  # numpy cannot make it an array


class FloatPairs(AgentAddon):
    def latent_pairs(self, j):
        return j.astype(float)


class OneLatent(AgentAddon):
    def batch_latents(self, j, t, z):
        return z  # not the pair (steps t, t + 1)


class BareReadout(AgentAddon):
    def encoder_readouts(self):
        return lambda h: h[:, -1]  # a function, not a list of them


class NarrowReadout(AgentAddon):
    def encoder_readouts(self):
        return [lambda h: h[:, -1, :3]]  # [N, 3], not [N, hidden]: met in the encoder's head


class Negative(AgentAddon):
    def stability_distance(self, j):
        return -np.ones(j.shape)  # R_stable would pay for changes


class Counter(AgentAddon):
    name = "counter"

    def __init__(self):
        self.n = 0

    def interaction_stored(self, j):
        self.n += 1
        return {}

    def state_dict(self):
        return {"n": self.n}

    def load_state_dict(self, state):
        self.n = state["n"]


class OtherTypes(AgentAddon):
    """Returns of other types that hold what each hook needs: taken."""

    def acting_latent(self):
        return np.zeros(10)  # float64

    def interaction_stored(self, j):
        return types.MappingProxyType({})

    def rl_interactions(self, j):
        return j.tolist()

    def batch_latents(self, j, t, z):
        return [z, z]
'''


@pytest.fixture
def edited_module(tmp_path, monkeypatch):
    """my_addons.py in the test's folder (its current directory), for a test that edits it:
    imported afresh (not another test's, imported before), and no edited one left behind for
    the next test on its worker."""
    monkeypatch.chdir(tmp_path)
    module = tmp_path / "my_addons.py"
    module.write_text(textwrap.dedent(PLUGIN))
    monkeypatch.syspath_prepend(tmp_path)
    sys.modules.pop("my_addons", None)
    yield module
    sys.modules.pop("my_addons", None)


def _train_with(run, addon):
    """Two interactions of a run with the add-on ``my_addons:ADDON``."""
    args = ["train", "--task", "circle-3", "--out", str(run), "--no-progress", *FAST_ARGS]
    assert main([*args, "--set", f"addons.plugins=my_addons:{addon}", "--interactions", "2"]) == 0


def _rows(run):
    with (run / "metrics.csv").open(newline="") as f:
        return list(csv.DictReader(f))


def test_a_users_addon_runs_writes_its_columns_and_stays_through_a_resume(
    tmp_path, monkeypatch, capsys
):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "my_addons.py").write_text(textwrap.dedent(PLUGIN))
    run = tmp_path / "run"
    args = ["train", "--task", "circle-3", "--out", str(run), "--no-progress", *FAST_ARGS]
    plugin = ["--set", "addons.plugins=my_addons:Constant"]
    assert main([*args, *plugin, "--interactions", "4"]) == 0
    assert main(["train", "--resume", str(run), "--interactions", "6", "--no-progress"]) == 0
    rows = _rows(run)
    assert [float(r["stability_reward"]) for r in rows] == [-0.37] * 6
    # the add-on's own count: built anew on resume, as its state is not checkpointed
    assert [r["stored"] for r in rows] == ["1", "2", "3", "4", "1", "2"]
    assert "not_declared" not in rows[0]
    assert all(float(r["task_reward"]) < 0 for r in rows)  # the task's: not an add-on's
    again = ["train", "--resume", str(run), "--interactions", "8", "--no-progress"]
    config = run / "config.json"
    # an add-on's path may change (a module renamed, as a task class's may): not another run
    config.write_text(config.read_text().replace("my_addons:Constant", "my_addons:Renamed"))
    assert main(again) == 2  # but this add-on declares another column
    assert "has columns stored that no add-on of the run (my_addons:Renamed) declares" in (
        capsys.readouterr().err
    )


def test_an_addon_scales_the_default_distance_through_the_public_function(tmp_path, monkeypatch):
    """The hook's docstring points at ``stability.change_after`` for the latents' own d (the
    agent's ``change_after`` would call the hook again)."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "my_addons.py").write_text(textwrap.dedent(PLUGIN))
    args = ["train", "--task", "circle-3", "--no-progress", "--interactions", "8", *FAST_ARGS]
    assert main([*args, "--out", str(tmp_path / "plain")]) == 0
    scaled = ["--set", "addons.plugins=my_addons:ScaledChange"]
    assert main([*args, *scaled, "--out", str(tmp_path / "scaled")]) == 0
    plain, doubled = (
        [float(r["stability_reward"]) for r in _rows(tmp_path / run)] for run in ("plain", "scaled")
    )
    assert doubled == [2 * d for d in plain] and min(plain) == -1.0


def test_a_run_records_its_addon_s_code_and_notes_a_resume_on_other_code(
    tmp_path, monkeypatch, capsys, edited_module
):
    """An add-on's settings are its class attributes, which the package's revision does not
    cover: the run records a digest of its module's file, and a resume on another says so."""
    module, run = edited_module, tmp_path / "run"
    _train_with(run, "Constant")
    key = "code of my_addons:Constant"
    record = json.loads((run / "config.json").read_text())
    assert record["versions"][key] == hashlib.sha256(module.read_bytes()).hexdigest()[:12]
    resume = ["train", "--resume", str(run), "--no-progress", "--interactions"]
    capsys.readouterr()
    assert main([*resume, "3"]) == 0  # the same code: nothing to note
    assert "continued" not in json.loads((run / "config.json").read_text())
    assert "goes on with other software" not in capsys.readouterr().err
    code = module.read_text()
    module.write_text(code.replace("0.37", "0.5"))
    del sys.modules["my_addons"]  # as a new process would import it
    assert main([*resume, "4"]) == 0
    before, after = (
        hashlib.sha256(t.encode()).hexdigest()[:12] for t in (code, module.read_text())
    )
    assert (
        f"sili train: note: {run} goes on with other software than it last ran with (code of "
        f"my_addons:Constant {before} -> {after}): its results mix both" in capsys.readouterr().err
    )
    (continued,) = json.loads((run / "config.json").read_text())["continued"]
    assert continued["from_interaction"] == 3
    assert continued["versions"][key] == hashlib.sha256(module.read_bytes()).hexdigest()[:12]
    assert [float(r["stability_reward"]) for r in _rows(run)] == [-0.37] * 3 + [-0.5]
    # the class renamed, its old name kept for the run: other code all the same
    renamed = module.read_text().replace("Constant", "Kept")
    module.write_text(renamed.replace("0.5", "0.6") + "\nConstant = Kept\n")
    del sys.modules["my_addons"]
    assert main([*resume, "5"]) == 0
    *_, again = json.loads((run / "config.json").read_text())["continued"]
    assert again["from_interaction"] == 4 and "code of my_addons:Kept" in again["versions"]


def test_a_run_recorded_by_an_earlier_version_goes_on_as_it_began(tmp_path, monkeypatch):
    """Without the code digests (not a difference) and with two add-ons sharing a column (a new
    run is refused that): resumed, as the README promises runs of earlier versions are."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "my_addons.py").write_text(textwrap.dedent(PLUGIN))
    run = tmp_path / "run"
    args = ["train", "--task", "circle-3", "--out", str(run), "--no-progress", *FAST_ARGS]
    assert main([*args, "--set", "addons.plugins=my_addons:Constant", "--interactions", "2"]) == 0
    config = json.loads((run / "config.json").read_text())
    config["versions"] = {k: v for k, v in config["versions"].items() if not k.startswith("code")}
    config["run"]["addons"]["plugins"] = "my_addons:Constant,my_addons:SameColumn"
    (run / "config.json").write_text(json.dumps(config))
    assert main(["train", "--resume", str(run), "--no-progress", "--interactions", "3"]) == 0
    assert "continued" not in json.loads((run / "config.json").read_text())


def test_an_addon_s_flags_and_numpy_numbers_are_written_as_numbers(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "my_addons.py").write_text(textwrap.dedent(PLUGIN))
    run = tmp_path / "run"
    args = ["train", "--task", "circle-3", "--out", str(run), "--no-progress", *FAST_ARGS]
    assert main([*args, "--set", "addons.plugins=my_addons:Flags", "--interactions", "3"]) == 0
    rows = _rows(run)
    assert [(r["odd"], r["seen"], r["half"]) for r in rows] == [
        ("0", "1", "0.0"),
        ("1", "1", "0.5"),
        ("0", "1", "1.0"),
    ]


def test_a_users_addon_that_cannot_be_built_is_named(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "my_addons.py").write_text(textwrap.dedent(PLUGIN))
    (tmp_path / "needs_dep.py").write_text("import not_installed\n")
    cases = {
        "no_such_module:X": r"cannot load add-on class 'no_such_module:X' \(No module named",
        "my_addons:Missing": r"cannot load add-on class 'my_addons:Missing' \(AttributeError",
        "my_addons:np": r"'my_addons:np' is not a subclass of AgentAddon",
        "my_addons:NotAnAddon": r"'my_addons:NotAnAddon' is not a subclass of AgentAddon",
        # a module that is there but imports what is missing: not "it must be ..."
        "needs_dep:A": r"\(No module named 'not_installed'\); importing needs_dep failed: fix it",
        "my_addons": r"add-on 'my_addons' names no class",
    }
    for path, message in cases.items():
        with pytest.raises(ConfigError, match=message):
            make_run_config("circle-3", "sili", settings={"addons.plugins": path})
    # worded for a run's record too (a resume from another folder), where nothing was given
    with pytest.raises(ConfigError, match=r"\); it must be package.module:ClassName of a subclass"):
        make_run_config("circle-3", "sili", settings={"addons.plugins": "no_such_module:X"})
    args = ["train", "--task", "circle-3", "--out", str(tmp_path / "r"), "--no-progress"]
    assert main([*args, "--set", "addons.plugins=my_addons:Configured"]) == 2
    err = capsys.readouterr().err
    assert "add-on my_addons:Configured is built with no arguments" in err
    assert "Traceback" not in err
    fresh = ["train", "--task", "circle-3", "--out", str(tmp_path / "u"), "--no-progress"]
    assert main([*fresh, "--set", "addons.plugins=my_addons:Usurper"]) == 2
    assert "declares metric_columns task_reward, which metrics.csv has already" in (
        capsys.readouterr().err
    )
    assert not (tmp_path / "u" / "config.json").exists()  # refused before a run was written
    assert main([*fresh, "--set", "addons.plugins=my_addons:Seeded"]) == 2
    assert "declares metric_columns seed, which a sweep's results.csv has already" in (
        capsys.readouterr().err
    )
    for bad in ("Letters", "Unnamed"):  # "score" wrote the columns s, c, o, r, e
        assert main([*fresh, "--set", f"addons.plugins=my_addons:{bad}"]) == 2
        assert f"my_addons:{bad} declares metric_columns" in capsys.readouterr().err
    plugins = "addons.plugins=my_addons:Constant,my_addons:Twin"  # one checkpoint entry by name
    assert main([*fresh, *FAST_ARGS, "--interactions", "1", "--set", plugins]) == 2
    assert "my_addons:Constant and my_addons:Twin are both named 'addon'" in capsys.readouterr().err
    plugins = "addons.plugins=my_addons:Constant, my_addons:Constant"
    assert main([*fresh, *FAST_ARGS, "--interactions", "1", "--set", plugins]) == 2
    assert "addons.plugins lists my_addons:Constant twice; give each once" in (
        capsys.readouterr().err
    )
    plugins = "addons.plugins=my_addons:Constant,my_addons:SameColumn"
    assert main([*fresh, *FAST_ARGS, "--interactions", "1", "--set", plugins]) == 2
    assert (
        "add-on my_addons:SameColumn declares metric_columns stored (my_addons:Constant), which "
        "another add-on of the run declares already" in capsys.readouterr().err
    )
    assert not (tmp_path / "u").exists()  # each refused before a run was written
    wrong = {
        "my_addons:Scalar": "add-on Scalar: stability_distance must return finite values >= 0 of "
        "j's shape (1,), got shape ()",
        "my_addons:NaN": "add-on NaN: stability_distance must return finite values >= 0 of j's "
        "shape (1,), got shape (1,) (not finite)",
        "my_addons:Negative": "add-on Negative: stability_distance must return finite values >= 0 "
        "of j's shape (1,), got shape (1,) (negative)",
        # the packaged posteriors add-on replaces d too: one of them would be ignored
        "my_addons:Constant --set addons.stability_distance=posterior": "add-ons "
        "HindsightPosteriors, Constant each replace stability_distance: keep one",
    }
    for plugins, message in wrong.items():
        given = ["--set", f"addons.plugins={plugins.split()[0]}", *plugins.split()[1:]]
        assert main([*args, *FAST_ARGS, "--interactions", "2", *given, "--overwrite"]) == 2
        assert message in capsys.readouterr().err
    with pytest.raises(TypeError, match="has no len"):  # its own error, as itself
        make_run_config("circle-3", "sili", settings={"addons.plugins": "my_addons:Buggy"})
        main([*args, "--set", "addons.plugins=my_addons:Buggy", "--overwrite"])


def test_a_hook_that_returns_the_wrong_thing_is_named_with_what_it_must_return(
    tmp_path, monkeypatch, capsys
):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "my_addons.py").write_text(textwrap.dedent(PLUGIN))
    wrong = {
        "NoValues": "interaction_stored must return a dict of its metric_columns' values, got None",
        "Tensor": "interaction_stored must return a number for its column stored, got "
        "tensor(0.5000)",
        "ShortLatent": "acting_latent must return None or an array of shape (10,), got an array "
        "of shape (3,) and dtype float32",
        "PastTheEnd": "latent_pairs must return an integer array of shape (32,) in [1, 2), got "
        "an array of shape (32,) and dtype int64, entries 3 to 3",  # at the first update
        "BeforeTheFirst": "rl_interactions must return an integer array of shape (",
        "AtTheEnd": "rl_interactions must return an integer array of shape (",  # [0, n): n
        "Ragged": "acting_latent must return None or an array of shape (10,), got "
        "[0.0, [1.0, 2.0]]",
        "FloatPairs": "latent_pairs must return an integer array of shape (32,) in [1, ",
        "OneLatent": "batch_latents must return None or two arrays of shape (",
        "BareReadout": "encoder_readouts must return a list of functions of per-step features "
        "[N, H, 32] to [N, 32], got <function BareReadout.",
        "NarrowReadout": "encoder_readouts must return a list of functions of per-step features "
        "[N, H, 32] to [N, 32] (given [2, H, hidden]), got (2, 3)",
    }
    errors = {}
    for name, message in wrong.items():
        run = ["train", "--task", "circle-3", "--out", str(tmp_path / name), "--no-progress"]
        plugin = ["--set", f"addons.plugins=my_addons:{name}"]
        assert main([*run, *FAST_ARGS, "--interactions", "5", *plugin]) == 2, name
        errors[name] = err = capsys.readouterr().err
        assert f"add-on {name}: {message}" in err
        assert "Traceback" not in err
    # a list of indices is shown as the array it makes, with its range
    assert re.search(
        r"in \[0, (\d+)\), got an array of shape \(\d+, \d+\) and dtype int64, "
        r"entries -1 to \d+$",
        errors["BeforeTheFirst"].strip(),
    ), errors["BeforeTheFirst"]
    run = ["train", "--task", "circle-3", "--out", str(tmp_path / "other"), "--no-progress"]
    other = ["--set", "addons.plugins=my_addons:OtherTypes"]
    assert main([*run, *FAST_ARGS, "--interactions", "5", *other]) == 0


def test_a_history_with_a_column_of_no_add_on_is_damaged_unless_the_run_has_add_ons(tmp_path):
    from sili_robots.metrics import METRIC_COLUMNS, check_history

    (tmp_path / "metrics.csv").write_text(",".join([*METRIC_COLUMNS, "my_note"]) + "\n")
    with pytest.raises(ConfigError, match="is damaged"):
        check_history(tmp_path, 0)
    with pytest.raises(ConfigError, match=r"my_note that no add-on of the run \(mine:A\) declares"):
        check_history(tmp_path, 0, plugins="mine:A")


def test_an_addon_renamed_since_its_checkpoint_is_named_with_the_states_it_holds(
    tmp_path, monkeypatch, capsys, edited_module
):
    """A checkpoint keeps each add-on's state by its ``name``: renamed, the add-on finds none,
    and its own error (a KeyError traceback) is named with the states the checkpoint holds."""
    module, run = edited_module, tmp_path / "run"
    _train_with(run, "Counter")
    module.write_text(module.read_text().replace('name = "counter"', 'name = "tally"'))
    del sys.modules["my_addons"]
    capsys.readouterr()
    assert main(["train", "--resume", str(run), "--no-progress", "--interactions", "3"]) == 2
    err = capsys.readouterr().err
    assert (
        "add-on Counter (name 'tally') could not load its state from the checkpoint: KeyError: "
        "'n'; the checkpoint holds states named ['counter']" in err
    )
    assert "Traceback" not in err


def test_a_sweeps_table_carries_the_columns_of_its_runs_addons(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "my_addons.py").write_text(textwrap.dedent(PLUGIN))
    out = tmp_path / "sweep"
    args = ["sweep", "--tasks", "circle-3", "--methods", "sac", "--seeds", "0", "--out", str(out)]
    args += ["--interactions", "2", "--workers", "1", "--no-progress", *FAST_ARGS]
    assert main([*args, "--set", "addons.plugins=my_addons:Flags"]) == 0
    table = pd.read_csv(out / "results.csv")
    assert list(table.columns[-3:]) == ["odd", "seen", "half"]
    assert table["half"].tolist() == [0.0, 0.5] and table["odd"].tolist() == [0, 1]
