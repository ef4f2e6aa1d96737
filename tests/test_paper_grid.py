"""The paper grid's machinery: a sweep's profile axis, results collections (``sili collect``),
``sili runs``, ``sili grid`` and ``sili claims``, on real (tiny) training runs."""

import gzip
import json
import shutil
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from cli_helpers import sili
from fast_settings import FAST_AGENT as FAST

from sili_robots import paper_grid
from sili_robots.bounds import stored_bounds
from sili_robots.build import default_profile
from sili_robots.claims import (
    HOLDS,
    NO,
    PART,
    Claim,
    claims_table,
    markdown,
    other_dynamics,
    run_finals,
    score,
)
from sili_robots.cli import main
from sili_robots.commands.claims import END, START, write_block
from sili_robots.paper_grid import BLOCKS, TASK_BUDGETS, block
from sili_robots.plot_data import load_results
from sili_robots.runs import SUMMARY
from sili_robots.sweep import LocalBackend, SweepSpec, expand, run_name, run_sweep
from sili_robots.sweep.results import results_table
from sili_robots.sweep.runner import plan
from sili_robots.sweep.state import run_path


@pytest.fixture(scope="module")
def sweep_and_collection(tmp_path_factory):
    """SILI in both profiles and SAC on Circle (3 Goals), 6 interactions; SAC left unfinished."""
    root = tmp_path_factory.mktemp("grid")
    sweep = root / "sweep"
    common = {"tasks": ["circle-3"], "seeds": [0], "interactions": 6, "agent_overrides": FAST}
    specs = [
        SweepSpec(methods=["sili", "sac"], **common),
        SweepSpec(methods=["sili"], profile="paper", **common),
    ]
    report = run_sweep(specs, sweep, LocalBackend(workers=2), progress=False)
    assert report.ok, report.failed
    (sweep / "runs" / "circle-3__sac__s0" / "summary.json").unlink()  # as if still training
    collection = root / "collection"
    assert main(["collect", str(sweep), "--into", str(collection)]) == 0
    return sweep, collection


def test_sweep_profile_names_and_records_the_paper_runs():
    (run,) = expand(
        SweepSpec(tasks=["circle-3"], methods=["sili"], seeds=[0], interactions=5, profile="paper")
    )
    assert run.name == "circle-3__sili-paper-b0.5__s0"
    assert run.config.agent.profile == "paper"
    assert run.config.agent.model.estimator == "gumbel"
    args = ["sweep", "--tasks", "circle-3", "--methods", "sili", "--out", "x", "--dry-run"]
    with pytest.raises(SystemExit) as exc:  # argparse's choices: exit 2 with the allowed values
        main([*args, "--profile", "papr"])
    assert exc.value.code == 2


def test_collection_keeps_finished_runs_small_and_identical(sweep_and_collection):
    sweep, collection = sweep_and_collection
    names = sorted(p.name for p in (collection / "runs").iterdir())
    assert names == ["circle-3__sili-bschedule__s0", "circle-3__sili-paper-b0.5__s0"]
    for name in names:
        files = sorted(p.name for p in (collection / "runs" / name).iterdir())
        assert files == ["config.json", "metrics.csv.gz", "summary.json"]
    a = results_table(sweep)
    b = results_table(collection)
    a = a[a.run.isin(names)].reset_index(drop=True)
    assert list(b.run.unique()) == names and (b.profile.unique() == ["package", "paper"]).all()
    pd.testing.assert_frame_equal(
        a.drop(columns="finished"), b.drop(columns="finished"), rtol=1e-6, check_dtype=False
    )
    # collecting again changes no byte; the gzip stream carries no timestamp
    before = (collection / "runs" / names[0] / "metrics.csv.gz").read_bytes()
    assert main(["collect", str(sweep), "--into", str(collection)]) == 0
    assert (collection / "runs" / names[0] / "metrics.csv.gz").read_bytes() == before
    assert gzip.decompress(before).startswith(b"interaction,")


def test_collect_reports_each_unfinished_run_once_and_not_one_collected_from_another_source(
    sweep_and_collection, tmp_path
):
    from sili_robots.sweep.collect import collect

    sweep, collection = sweep_and_collection
    copy = tmp_path / "sweep"
    shutil.copytree(sweep, copy)
    (copy / "runs" / "circle-3__sili-bschedule__s0" / "summary.json").unlink()
    report = collect([copy, collection, copy], tmp_path / "into")
    assert report.unfinished == ["circle-3__sac__s0"]  # was listed per source, and bschedule too
    assert sorted(report.added) == ["circle-3__sili-bschedule__s0", "circle-3__sili-paper-b0.5__s0"]


def test_a_finished_run_without_its_metrics_is_unfinished_and_the_others_collected(
    sweep_and_collection, tmp_path
):
    from sili_robots.sweep.collect import collect

    sweep, _ = sweep_and_collection
    gone = tmp_path / "sweep"
    shutil.copytree(sweep, gone)
    (gone / "runs" / "circle-3__sili-paper-b0.5__s0" / "metrics.csv").unlink()
    report = collect([gone], tmp_path / "into")
    assert sorted(report.unfinished) == ["circle-3__sac__s0", "circle-3__sili-paper-b0.5__s0"]
    assert report.added == ["circle-3__sili-bschedule__s0"]


def test_collect_refuses_a_different_run_of_the_same_name(sweep_and_collection, tmp_path, capsys):
    sweep, collection = sweep_and_collection
    other = tmp_path / "other"
    shutil.copytree(collection, other)
    cfg_path = other / "runs" / "circle-3__sili-bschedule__s0" / "config.json"
    cfg = json.loads(cfg_path.read_text())
    cfg["run"]["checkpoint_every"] += 5  # saved more often: the same run
    cfg_path.write_text(json.dumps(cfg))
    assert main(["collect", str(sweep), "--into", str(other)]) == 0
    cfg["run"]["seed"] = 7
    cfg_path.write_text(json.dumps(cfg))
    assert main(["collect", str(sweep), "--into", str(other)]) == 2
    err = capsys.readouterr().err
    assert "holds a different run named circle-3__sili-bschedule__s0 (seed: 7 there, 0 here;" in err
    assert err.rstrip().endswith("collect the other into another folder (--into)")
    assert main(["collect", str(tmp_path / "nothing"), "--into", str(other)]) == 2
    run = sweep / "runs" / "circle-3__sac__s0"
    before = {p.name: p.read_bytes() for p in run.iterdir() if p.is_file()}
    for into, said in (
        (sweep, f"--into {sweep} is a sweep; collect into a results collection"),  # its runs
        (run, f"--into {run} is not a sweep or a results collection but holds files"),
    ):
        assert main(["collect", str(collection), "--into", str(into)]) == 2
        assert said in capsys.readouterr().err
    assert {p.name: p.read_bytes() for p in run.iterdir() if p.is_file()} == before
    assert not (run / "runs").exists()


def test_grid_refuses_a_sweep_as_its_collection_and_names_a_damaged_collected_config(
    sweep_and_collection, tmp_path, capsys
):
    sweep, collection = sweep_and_collection
    grid = ["grid", "--tasks", "circle-3", "--blocks", "sili-oracle", "--dry-run"]
    assert main([*grid, "--sweep-dir", str(tmp_path / "s"), "--into", str(sweep)]) == 2
    assert (
        f"--into {sweep} is a sweep; collect into a results collection" in capsys.readouterr().err
    )
    damaged = tmp_path / "damaged"
    shutil.copytree(collection, damaged)
    config = damaged / "runs" / "circle-3__sili-bschedule__s0" / "config.json"
    for text in ("{", '{"run": 5}', "[]", "{}"):
        config.write_text(text)
        assert main([*grid, "--sweep-dir", str(tmp_path / "s"), "--into", str(damaged)]) == 2
        assert f"{config} is damaged" in capsys.readouterr().err


def test_collect_takes_a_run_extended_or_trained_again_and_refuses_before_copying(
    sweep_and_collection, tmp_path, capsys
):
    sweep, collection = sweep_and_collection
    name, paper = "circle-3__sili-bschedule__s0", "circle-3__sili-paper-b0.5__s0"
    source, into = tmp_path / "sweep", tmp_path / "collection"
    shutil.copytree(sweep, source)
    shutil.copytree(collection, into)
    run = source / "runs" / name
    assert main(["train", "--resume", str(run), "--interactions", "8", "--no-progress"]) == 0
    cfg = json.loads((run / "config.json").read_text())
    cfg["versions"]["sili_robots"] = "0.0.1"  # trained again by another version
    (run / "config.json").write_text(json.dumps(cfg))
    capsys.readouterr()
    assert main(["collect", str(source), "--into", str(into)]) == 0
    report = json.loads(capsys.readouterr().out)  # the longer run replaced its copy: said so
    assert report["replaced"] == [name] and name not in report["added"]
    metrics = gzip.decompress((into / "runs" / name / "metrics.csv.gz").read_bytes())
    assert len(metrics.decode().strip().splitlines()) == 1 + 8
    assert json.loads((into / "runs" / name / "summary.json").read_text())["interactions"] == 8
    # another run under a name already taken: refused before anything is copied
    shutil.rmtree(into / "runs" / name)
    other = json.loads((into / "runs" / paper / "config.json").read_text())
    other["run"]["seed"] = 7
    (into / "runs" / paper / "config.json").write_text(json.dumps(other))
    capsys.readouterr()
    assert main(["collect", str(source), "--into", str(into)]) == 2
    assert f"holds a different run named {paper}" in capsys.readouterr().err
    assert not (into / "runs" / name).exists()
    # of one run in two sources the longer is kept, whatever their order; two runs clash
    for sources in ([sweep, source], [source, sweep]):
        fresh = tmp_path / f"fresh-{len(list(tmp_path.iterdir()))}"
        assert main(["collect", *map(str, sources), "--into", str(fresh)]) == 0
        summary = json.loads((fresh / "runs" / name / "summary.json").read_text())
        assert summary["interactions"] == 8
        assert main(["collect", str(sweep), "--into", str(fresh)]) == 0  # the shorter: kept out
        assert json.loads((fresh / "runs" / name / "summary.json").read_text()) == summary
    (source / "runs" / paper / "config.json").write_text(json.dumps(other))
    capsys.readouterr()
    assert main(["collect", str(sweep), str(source), "--into", str(tmp_path / "two")]) == 2
    assert f"holds a different run named {paper}" in capsys.readouterr().err
    assert not (tmp_path / "two" / "runs").exists()


def test_a_run_collected_back_into_a_sweep_replaces_a_shorter_training_there(
    sweep_and_collection, tmp_path
):
    """`sili grid` copies collected runs back into its sweep: a shorter training left in a run's
    folder must not stay beside the copy, where its rows would be read first."""
    from sili_robots.metrics import metrics_file
    from sili_robots.sweep.collect import collect
    from sili_robots.sweep.state import run_state

    sweep, collection = sweep_and_collection
    name = "circle-3__sili-bschedule__s0"
    into = tmp_path / "sweep"
    shutil.copytree(sweep, into)
    run = into / "runs" / name
    lines = (run / "metrics.csv").read_text().splitlines(keepends=True)
    assert (run / "checkpoint.pt").is_file() and len(lines) == 1 + 6
    assert collect([collection], into, names=[name]).unchanged == [name]  # the same run, done
    assert (run / "checkpoint.pt").is_file()  # kept: the run can be extended from it
    (run / "summary.json").unlink()
    (run / "metrics.csv").write_text("".join(lines[:5]))  # stopped after 4 of the 6
    assert collect([collection], into, names=[name]).replaced == [name]
    assert not (run / "metrics.csv").exists() and not (run / "checkpoint.pt").exists()
    assert metrics_file(run).name == "metrics.csv.gz" and run_state(run) == "done"
    # a training there past the collected length (an extension under way) is left alone
    (run / "summary.json").unlink()
    (run / "metrics.csv").write_text("".join(lines + lines[1:3]))
    assert collect([collection], into, names=[name]).unchanged == [name]
    assert len((run / "metrics.csv").read_text().splitlines()) == 1 + 8


def test_runs_counts_runs_and_interactions(sweep_and_collection, capsys, monkeypatch):
    sweep, collection = sweep_and_collection
    assert main(["runs", str(sweep)]) == 0
    out = capsys.readouterr().out
    assert out.strip().splitlines()[-1].startswith("2 runs done, 1 unfinished; 18 interactions")
    monkeypatch.chdir(sweep)
    for here in (".", "./"):  # the current folder, which has no name of its own
        assert main(["runs", here]) == 0
        assert capsys.readouterr().out == out
    assert main(["runs", str(collection), "--csv"]) == 0
    table = pd.read_csv(__import__("io").StringIO(capsys.readouterr().out))
    assert sorted(table.profile) == ["package", "paper"] and table.done.tolist() == [1, 1]


def test_runs_of_one_variant_with_other_settings_are_rows_of_their_own(
    sweep_and_collection, tmp_path, capsys
):
    _, collection = sweep_and_collection
    mixed = tmp_path / "mixed"
    run = collection / "runs" / "circle-3__sili-bschedule__s0"
    for seed, lr in ((0, None), (1, None), (2, 0.002)):  # seed 2 with --set sac.lr=0.002
        copy = mixed / "runs" / f"s{seed}"
        shutil.copytree(run, copy)
        config = json.loads((copy / "config.json").read_text())
        config["run"]["seed"] = seed
        config["run"]["threads"] = 1 + seed % 2  # bookkeeping, not a setting
        if seed == 1:  # another machine's default precision: the machine's, not a setting
            sac = config["run"]["agent"]["sac"]
            sac["precision"] = "float32" if sac["precision"] == "bfloat16" else "bfloat16"
        if seed == 1:  # the task's default spelled out: the same dynamics
            config["run"]["env_kwargs"] = {"outside_margin": 0.1}
        if lr is not None:
            config["run"]["agent"]["sac"]["lr"] = lr
        (copy / "config.json").write_text(json.dumps(config))
    assert main(["runs", str(mixed), "--csv"]) == 0
    table = pd.read_csv(__import__("io").StringIO(capsys.readouterr().out)).fillna("")
    lr = json.loads((run / "config.json").read_text())["run"]["agent"]["sac"]["lr"]
    assert sorted(zip(table.settings, table.seeds.astype(str), strict=True)) == [
        (f"agent.sac.lr={json.dumps(lr)}", "0,1"),
        ("agent.sac.lr=0.002", "2"),
    ]
    assert main(["runs", str(collection), "--csv"]) == 0  # runs that agree: no settings named
    table = pd.read_csv(__import__("io").StringIO(capsys.readouterr().out)).fillna("")
    assert (table.settings == "").all()


def test_runs_lists_b_values_in_numeric_order(sweep_and_collection, tmp_path, capsys):
    """Run names sort b0.5 before b0 and b1 ("." before "_"): the table followed them."""
    _, collection = sweep_and_collection
    run = collection / "runs" / "circle-3__sili-bschedule__s0"
    for b in ("0.5", "0", "1"):
        copy = tmp_path / "b" / "runs" / f"circle-3__sili-b{b}__s0"
        shutil.copytree(run, copy)
        config = json.loads((copy / "config.json").read_text())
        config["run"]["agent"]["sili"]["beta"] = float(b)
        (copy / "config.json").write_text(json.dumps(config))
    assert sorted(p.name for p in (tmp_path / "b" / "runs").iterdir())[0].endswith("b0.5__s0")
    assert main(["runs", str(tmp_path / "b"), "--csv"]) == 0
    table = pd.read_csv(__import__("io").StringIO(capsys.readouterr().out))
    assert table.config_beta.tolist() == [0.0, 0.5, 1.0]


def test_plot_reads_a_collection_without_writing_into_it(sweep_and_collection, tmp_path, capsys):
    _, collection = sweep_and_collection
    df = load_results(collection)
    assert set(df.run) == {"circle-3__sili-bschedule__s0", "circle-3__sili-paper-b0.5__s0"}
    capsys.readouterr()
    args = ["plot", str(collection), "--out", str(tmp_path / "fig"), "--formats", "png,png"]
    assert main(args) == 0
    assert (tmp_path / "fig" / "circle-3.png").is_file()
    written = capsys.readouterr().out.split()
    assert len(written) == len(set(written)) == 2  # the task's figure and the overview, once
    assert not (collection / "results.csv").exists()


def test_grid_progress_counts_only_runs_at_the_blocks_budget(
    sweep_and_collection, tmp_path, capsys
):
    _, collection = sweep_and_collection  # holds circle-3__sili-bschedule__s0 at 6 interactions
    args = ["grid", "--dry-run", "--blocks", "sili-oracle", "--tasks", "circle-3"]
    args += ["--sweep-dir", str(tmp_path / "no-sweep"), "--into"]  # a fresh clone's
    assert main([*args, str(collection)]) == 0
    assert "6 runs, 0 done" in capsys.readouterr().out
    committed = Path(__file__).resolve().parents[1] / "results" / "paper-grid"
    assert main([*args, str(committed)]) == 0
    assert capsys.readouterr().out.strip().splitlines()[-1] == (
        f"6 of 6 runs done, 12,000 of 12,000 interactions (in {tmp_path / 'no-sweep'} or "
        f"{committed})"  # where it looked: a count of 0 from elsewhere says why
    )


def test_grid_checks_its_folders_and_selection_before_any_run(
    sweep_and_collection, tmp_path, capsys
):
    a_file = tmp_path / "file"
    a_file.write_text("x")
    dry = ["grid", "--dry-run", "--blocks", "b-sweep", "--tasks", "circle-3"]
    for option in ("--sweep-dir", "--into"):
        assert main([*dry, option, str(a_file)]) == 2
        assert f"{option} {a_file} is a file" in capsys.readouterr().err
    elsewhere = ["--sweep-dir", str(tmp_path / "s"), "--into", str(tmp_path / "c")]
    assert (
        main(["grid", "--dry-run", "--blocks", "b-sweep", "--tasks", "circle-8", *elsewhere]) == 2
    )
    assert "b-sweep run nothing on circle-8" in capsys.readouterr().err
    _, collection = sweep_and_collection
    summary = collection / "runs" / "circle-3__sili-bschedule__s0" / "summary.json"
    intact = summary.read_text()
    summary.write_text("{half")  # the collection is shared with other tests: put it back
    try:
        args = ["grid", "--dry-run", "--blocks", "sili-oracle", "--tasks", "circle-3"]
        assert main([*args, "--sweep-dir", str(tmp_path / "s"), "--into", str(collection)]) == 2
        assert f"{summary} is damaged" in capsys.readouterr().err
    finally:
        summary.write_text(intact)
    assert not (tmp_path / "s").exists() and not (tmp_path / "c").exists()


def test_grid_outside_the_repository_trains_nothing_without_its_folders(
    tmp_path, monkeypatch, capsys
):
    monkeypatch.chdir(tmp_path)  # no sweeps/paper-grid, no results/paper-grid here
    args = ["grid", "--blocks", "b-sweep", "--workers", "1"]
    assert main(args) == 2
    err = capsys.readouterr().err
    assert f"neither sweeps/paper-grid nor results/paper-grid exists here ({tmp_path})" in err
    assert "give --sweep-dir and --into to train it afresh there" in err
    assert list(tmp_path.iterdir()) == []
    assert main([*args, "--dry-run"]) == 0  # a listing says the same and goes on
    assert "neither exists here; run from the repository root" in capsys.readouterr().out


def test_grid_blocks_and_budgets(capsys, monkeypatch, tmp_path):
    assert (
        main(
            [
                "grid",
                "--dry-run",
                "--blocks",
                "sili-oracle",
                "--tasks",
                "driving",
                "--sweep-dir",
                "/nonexistent/sweep",
                "--into",
                "/nonexistent/collection",
            ]
        )
        == 0
    )
    assert capsys.readouterr().out.strip().splitlines() == [
        "sili-oracle on driving (2500 interactions): 6 runs, 0 done",
        "0 of 6 runs done, 0 of 15,000 interactions (in /nonexistent/sweep or "
        "/nonexistent/collection)",
    ]
    (spec,) = block("stable-smirl").specs(("circle-8",))
    assert spec.interactions == TASK_BUDGETS["circle-8"] // 2 and spec.methods == [
        "stable",
        "smirl",
    ]
    assert [b.name for b in BLOCKS[:2]] == ["sili-oracle", "paper-profile"]
    # float32 products in every block, whatever precision the machine would choose: here one
    # where bfloat16 wins the timing (a CPU with bfloat16 units)
    from sili_robots.agent import matmul
    from sili_robots.agent.config import AgentConfig

    monkeypatch.setenv("SILI_ROBOTS_CACHE", str(tmp_path))
    monkeypatch.setattr(matmul, "time_matmuls", lambda: {"onednn": 1e-3, "aten": 1e-3})
    monkeypatch.setattr(matmul, "time_precisions", lambda _m: {"float32": 1e-2, "bfloat16": 1e-3})
    assert AgentConfig().sac.precision == "bfloat16"
    for b in BLOCKS:
        for planned in plan(b.specs()):
            assert planned.config.agent.sac.precision == "float32", planned.name
    assert main(["grid", "--dry-run", "--tasks", "circle-9"]) == 2
    assert main(["grid", "--dry-run", "--blocks", "everything"]) == 2
    capsys.readouterr()
    for option, empty in (("--blocks", ""), ("--tasks", ",")):  # a slip, not "all"
        assert main(["grid", "--dry-run", option, empty]) == 2
        assert f"{option} {empty!r} names none; allowed: " in capsys.readouterr().err


# ---------------------------------------------------------------- the claims' decision rules
def _rows(
    task, task_id, method, seed, rewards, stability, profile=None, beta=0.5, name=None, args=""
):
    """A run's rows in the results table, named as the grid names it (unless ``name``); in the
    task's profile for the method unless ``profile``; ``args``: its other task arguments."""
    n = len(rewards)
    profile = profile or default_profile(task, method)
    if name is None:
        label = {"sili": "schedule" if profile == "package" else 0.5, "smirl": 0.5}.get(method)
        name = run_name(task, method, seed, beta=label, profile=profile)
    return pd.DataFrame(
        {
            "run": name,
            "task": task,
            "task_id": task_id,
            "method": method,
            "task_args": args,
            "profile": profile,
            "config_beta": beta,
            "seed": seed,
            "interaction": np.arange(n),
            "task_reward": rewards,
            "true_stability": stability,
        }
    )


def _const(n, value):
    return np.full(n, float(value))


def _planned_rows(block_name, task, task_id, curves):
    """Rows of every run a block plans on ``task``: ``curves[method](n)`` -> (rewards,
    stability) of a run of n interactions."""
    parts = []
    for r in plan(block(block_name).specs((task,))):
        c, n = r.config, r.config.interactions
        rewards, stability = curves[c.method](n)
        beta = c.agent.sili.beta if isinstance(c.agent.sili.beta, float) else 0.5
        parts.append(_rows(task, task_id, c.method, c.seed, rewards, stability, beta=beta,
                           name=r.name))  # fmt: skip
    return parts


@pytest.mark.parametrize(
    ("best_b", "b0_reward", "verdict"),
    [(0.6, -20.0, HOLDS), (0.6, -6.5, PART), (0.4, -20.0, HOLDS), (0.8, -20.0, HOLDS)],
)
def test_the_sweet_spot_holds_only_where_the_best_b_stands_clear_of_both_ends(
    best_b, b0_reward, verdict
):
    """Best at b=0.6, or at either end of the range (0.4, 0.8, both in it); b=0 within 0.05 of
    its score in the second: in range, not apart."""
    reward = {0.0: b0_reward, 0.2: -15.0, 0.4: -10.0, 0.6: -10.0, 0.8: -10.0, 1.0: -20.0}
    reward[best_b] = -6.0
    parts = []
    for b in reward:
        for seed in range(5):
            name = run_name("circle-3", "sili", seed, beta=b)
            rewards, held = _const(1000, reward[b]), _const(1000, 1)
            parts.append(_rows("circle-3", "sili/Circle3-v1", "sili", seed, rewards, held,
                               beta=b, name=name))  # fmt: skip
    (claim,) = [c for c in claims_table(pd.concat(parts)) if c.claim == "b sweet spot 0.4-0.8"]
    assert claim.verdict == verdict, claim
    if verdict == PART:
        assert claim.short_of == "b=0.6 not above both ends by more than 0.05"


@pytest.mark.parametrize(
    ("stable_from", "verdict"), [(200, HOLDS), (500, PART), (355, HOLDS), (356, PART)]
)
def test_speaker_listener_needs_sili_stable_by_about_250(stable_from, verdict):
    """SILI above LILI, SAC and SMiRL in all; held from interaction 200, or only from 500; the
    first stable window at 350 (the bound, included) holds, at 351 does not."""

    def sili(n):
        return _const(n, -3.0), np.r_[_const(stable_from, 0), _const(n - stable_from, 1)]

    def baseline(n):
        return _const(n, -30.0), _const(n, 0)

    curves = {"sili": sili, "oracle": baseline, "lili": baseline, "sac": baseline,
              "stable": baseline, "smirl": baseline}  # fmt: skip
    task, task_id = "speaker-listener", "sili/SpeakerListener-v1"
    parts = [p for b in ("sili-oracle", "lili-sac", "stable-smirl")
             for p in _planned_rows(b, task, task_id, curves)]  # fmt: skip
    (claim,) = [c for c in claims_table(pd.concat(parts)) if c.claim.startswith("SILI stable by")]
    assert claim.verdict == verdict, claim
    first = stable_from - 5  # the first window of 50 with 45 held
    assert f"first stable at {first}, {first}, {first};" in claim.measured
    if verdict == PART:
        assert claim.short_of == "not stable by 350 in every seed"


def test_speaker_listener_s_sili_must_beat_oracle_too():
    """The paper: SILI "outperforms all other baselines in task reward, including Oracle" (and
    Stable, which "does not optimize for the task reward")."""

    def sili(n):
        return _const(n, -20.0), _const(n, 1)

    def curve(reward):
        return lambda n: (_const(n, reward), _const(n, 0))

    curves = {"sili": sili, "oracle": curve(-10.0), "lili": curve(-30.0), "sac": curve(-30.0),
              "stable": curve(-30.0), "smirl": curve(-30.0)}  # fmt: skip
    task, task_id = "speaker-listener", "sili/SpeakerListener-v1"

    def decided():
        parts = [p for b in ("sili-oracle", "lili-sac", "stable-smirl")
                 for p in _planned_rows(b, task, task_id, curves)]  # fmt: skip
        claims = claims_table(pd.concat(parts))
        (claim,) = [c for c in claims if c.claim.startswith("SILI stable by")]
        return claim

    claim = decided()
    assert claim.verdict == PART and claim.short_of == "not above Oracle", claim
    curves |= {"oracle": curve(-30.0), "stable": curve(-10.0)}  # Stable, at half the budget
    claim = decided()
    assert claim.verdict == PART and claim.short_of == "not above Stable", claim


def test_score_is_zero_at_standing_still_and_one_at_the_oracle():
    assert score(-50.0, "sili/Circle3-v1") == pytest.approx(0.0)
    assert score(-3.8568, "sili/Circle3-v1") == pytest.approx(1.0)
    assert score(-0.25, "sili/Driving-v0") == pytest.approx(0.75)


@pytest.mark.parametrize(("sili_reward", "verdict"), [(-6.0, HOLDS), (-12.0, PART), (-30.0, NO)])
def test_comparable_to_oracle(sili_reward, verdict):
    n = 2000
    parts = [
        _rows("circle-3", "sili/Circle3-v1", "sili", s, _const(n, sili_reward), _const(n, 1))
        for s in range(3)
    ] + [
        _rows("circle-3", "sili/Circle3-v1", "oracle", s, _const(n, -4.5), _const(n, 0))
        for s in range(3)
    ]
    claims = claims_table(pd.concat(parts, ignore_index=True))
    first = claims[0]
    assert first.task == "circle-3" and first.claim == "SILI comparable to Oracle"
    assert first.verdict == verdict
    # everything else has no runs: said so, never decided
    assert all(c.verdict.startswith("not measured yet") for c in claims[1:])
    assert "| circle-3 |" in markdown(claims)


def test_a_task_version_without_reference_bounds_is_not_decided(monkeypatch):
    n = 2000
    parts = [
        _rows("circle-3", "sili/Circle3-v9", m, s, _const(n, r), _const(n, 1))
        for m, r in (("sili", -30.0), ("oracle", -4.5))
        for s in range(3)
    ]
    first = claims_table(pd.concat(parts, ignore_index=True))[0]
    assert first.verdict.startswith("not measured yet (no reference bounds for sili/Circle3-v9")
    # bounds that give no range to score in are no bounds either
    flat = {"still": {"task_reward": -50.0}, "oracle": {"task_reward": -50.0}}
    monkeypatch.setattr("sili_robots.claims.stored_bounds", lambda task_id: flat)
    assert np.isnan(score(-10.0, "sili/Circle3-v1"))


def test_a_run_short_of_its_budget_or_outside_the_grid_does_not_count():
    parts = [
        _rows("circle-3", "sili/Circle3-v1", m, s, _const(1999, -5), _const(1999, 1))
        for m in ("sili", "oracle")
        for s in range(3)
    ]
    # full-budget runs that are not the grid's: another latent kind, another seed
    parts.append(_rows("circle-3", "sili/Circle3-v1", "sili", 0, _const(2000, -5), _const(2000, 1),
                       name="circle-3__sili-continuous-bschedule__s0"))  # fmt: skip
    parts.append(_rows("circle-3", "sili/Circle3-v1", "sili", 5, _const(2000, -5), _const(2000, 1)))
    first = claims_table(pd.concat(parts, ignore_index=True))[0]
    assert first.verdict == "not measured yet (runs at the grid's budget: SILI 0/3, Oracle 0/3)"
    # the grid's names and budget on other dynamics (an ablation's --env-kwarg) count only on
    # the task's own dynamics
    ablation = '{"outside_margin": 0.5}'
    parts = [
        _rows("circle-3", "sili/Circle3-v1", m, s, _const(2000, -5), _const(2000, 1), args=ablation)
        for m in ("sili", "oracle")
        for s in range(3)
    ]
    df = pd.concat(parts, ignore_index=True)
    assert claims_table(df)[0].verdict == first.verdict
    assert len(other_dynamics(df)) == 6
    assert claims_table(df.assign(task_args=""))[0].verdict == HOLDS


def test_above_baselines_compares_smirl_over_its_own_interactions():
    n, half = 2000, 1000
    # SILI is at -40 until 1000 and -5 after; SMiRL stops at 1000 with -30: at the same point
    # SILI (-40) is below it, although SILI's final window (-5) is far above
    sili_curve = np.r_[_const(half, -40), _const(half, -5)]
    parts = [
        _rows("circle-8", "sili/Circle8-v1", "sili", s, sili_curve, _const(n, 1)) for s in range(3)
    ]
    for method, value, length in (("lili", -20, n), ("sac", -50, n), ("smirl", -30, half)):
        parts += [
            _rows(
                "circle-8", "sili/Circle8-v1", method, s, _const(length, value), _const(length, 0)
            )
            for s in range(3)
        ]
    claims = claims_table(pd.concat(parts, ignore_index=True))
    (above,) = [c for c in claims if c.task == "circle-8" and c.claim.startswith("SILI above")]
    assert above.verdict == PART  # above LILI and SAC, not SMiRL
    assert "SMiRL 0.43" in above.measured
    assert above.short_of == "not above SMiRL"  # the part that falls short, in the table too
    assert "| **holds in part**: not above SMiRL |" in markdown(claims)


def test_above_is_more_than_the_margin(monkeypatch):
    """A baseline exactly the margin below SILI is not beaten (a margin of 0.25 and scores
    that are binary fractions: sums without rounding)."""
    monkeypatch.setattr("sili_robots.claims.ABOVE", 0.25)
    bounds = {"still": {"task_reward": 0.0}, "oracle": {"task_reward": 1.0}}
    monkeypatch.setattr("sili_robots.claims.stored_bounds", lambda _task_id: bounds)
    n, task, task_id = 2000, "circle-8", "sili/Circle8-v1"
    parts = [_rows(task, task_id, "sili", s, _const(n, 0.5), _const(n, 1)) for s in range(3)]
    for method, value, length in (("lili", 0.25, n), ("sac", 0.0, n), ("smirl", 0.0, n // 2)):
        parts += [_rows(task, task_id, method, s, _const(length, value), _const(length, 0))
                  for s in range(3)]  # fmt: skip
    claims = claims_table(pd.concat(parts, ignore_index=True))
    (above,) = [c for c in claims if c.task == task and c.claim.startswith("SILI above")]
    assert (above.verdict, above.short_of) == (PART, "not above LILI")


@pytest.mark.parametrize(("sili_early_rate", "verdict"), [(0.0, HOLDS), (0.5, NO)])
def test_driving_only_sili_avoids_collisions(sili_early_rate, verdict):
    """Others collide in 30% of interactions; SILI in none at the end, but in
    ``sili_early_rate`` until 1,250, where Stable and SMiRL (half budget) are compared with it."""
    early = -(np.arange(1250) % 10 < sili_early_rate * 10).astype(float)
    driving = _driving_claim(lambda _seed: np.r_[early, np.zeros(1250)])
    assert driving.verdict == verdict
    assert driving.measured.startswith("collision rate SILI 0%; Oracle 30% (SILI 0%)")
    assert f"SMiRL 30% (SILI {sili_early_rate:.0%})" in driving.measured


def test_driving_s_claim_holds_only_if_every_sili_seed_is_clean():
    """Seeds 0 and 1 never collide, seed 2 in 2% of its interactions: the mean is within 1%,
    the claim ("every SILI seed") is not."""
    collided = -(np.arange(2500) % 50 == 0).astype(float)
    claim = _driving_claim(lambda seed: collided if seed == 2 else np.zeros(2500))
    assert (claim.verdict, claim.short_of) == (PART, "a SILI seed collides in over 1%")


def test_driving_s_claim_needs_every_other_method_to_collide():
    """SILI never collides, Oracle in 1% of its interactions: fewer than Oracle, in part."""
    claim = _driving_claim(lambda _seed: np.zeros(2500), oracle_every=100)
    assert (claim.verdict, claim.short_of) == (PART, "at most 1% for Oracle too")


def _driving_claim(sili: Callable[[int], np.ndarray], oracle_every: int = 0) -> Claim:
    """Driving's collision claim, SILI's seed s earning ``sili(s)`` over 2,500 interactions and
    the others colliding in 30% of theirs (Stable and SMiRL at half the budget, as planned;
    ``oracle_every``: Oracle once in so many interactions instead)."""
    budgets = {"oracle": 2500, "lili": 2500, "sac": 2500, "stable": 1250, "smirl": 1250}
    parts = [
        _rows("driving", "sili/Driving-v0", "sili", s, sili(s), _const(2500, 1)) for s in range(3)
    ]
    for method, n in budgets.items():
        collided = -(np.arange(n) % 10 < 3).astype(float)
        if method == "oracle" and oracle_every:
            collided = -(np.arange(n) % oracle_every == 0).astype(float)
        parts += [
            _rows("driving", "sili/Driving-v0", method, s, collided, _const(n, 1)) for s in range(3)
        ]
    claims = claims_table(pd.concat(parts, ignore_index=True))
    (driving,) = [c for c in claims if c.claim == "only SILI avoids all collisions"]
    return driving


def _reward_at(task_id: str, target: float) -> float:
    """The task reward whose score (0 standing still, 1 Oracle's reference) is ``target``."""
    bounds = stored_bounds(task_id)
    still, best = bounds["still"]["task_reward"], bounds["oracle"]["task_reward"]
    return still + target * (best - still)


@pytest.mark.parametrize(
    ("below", "held", "verdict"), [(0.05, 1, PART), (0.5, 1, HOLDS), (0, 0, NO)]
)
def test_stable_s_poor_reward_needs_a_score_clear_of_silis(below, held, verdict):
    """Stable holds as SILI does but scores 0.05 below it: within the 0.1 margin, so the paper's
    "Stable earns little" is shown in part; 0.5 below: in full; neither holding nor below: not."""
    task_id = "sili/Circle3-v1"
    stable = _reward_at(task_id, score(-6.0, task_id) - below)
    parts = [
        _rows("circle-3", task_id, "sili", s, _const(2000, -6.0), _const(2000, 1)) for s in range(3)
    ]
    curves = {
        "stable": lambda n: (_const(n, stable), _const(n, held)),
        "smirl": lambda n: (_const(n, -50.0), _const(n, 0.0)),
    }
    parts += _planned_rows("stable-smirl", "circle-3", task_id, curves)
    claims = claims_table(pd.concat(parts, ignore_index=True))
    (claim,) = [c for c in claims if c.task == "circle-3" and c.claim.startswith("Stable")]
    assert claim.verdict == verdict, claim
    # only a verdict in part says what falls short
    short_of = {PART: "score not more than 0.1 below SILI's"}.get(verdict, "")
    assert claim.short_of == short_of


@pytest.mark.parametrize(("paper_reward", "verdict"), [(-30.0, HOLDS), (-6.0, PART), (-2.0, NO)])
def test_the_default_profile_is_decided_against_the_paper_profile(paper_reward, verdict):
    rows = _profile_claims(paper_reward)
    assert set(rows) == {"circle-3", "driving"}
    assert rows["circle-3"].verdict == verdict
    assert rows["circle-3"].measured.startswith("3 seeds each: score package 0.95 (reward -6.00")
    assert (
        rows["driving"].verdict
        == "not measured yet (runs at the grid's budget: package 0/5, paper 0/5)"
    )


def test_a_paper_profile_a_little_ahead_leaves_the_default_in_range():
    """The paper profile scores 0.03 above the package's: within the 0.05 margin, as equal."""
    paper = _reward_at("sili/Circle3-v1", score(-6.0, "sili/Circle3-v1") + 0.03)
    claim = _profile_claims(paper)["circle-3"]
    assert (claim.verdict, claim.short_of) == (PART, "within 0.05")


def _profile_claims(paper_reward: float) -> dict:
    """The profile claim per task, Circle (3 Goals)'s package runs at -6.0 and its paper
    profile runs at ``paper_reward``."""
    n = 2000
    paper_names = [r.name for r in plan(block("paper-profile").specs(("circle-3",)))]
    parts = [
        _rows("circle-3", "sili/Circle3-v1", "sili", s, _const(n, -6.0), _const(n, 1))
        for s in range(3)
    ]
    for s, name in enumerate(paper_names):
        paper = _const(n, paper_reward)
        parts.append(_rows("circle-3", "sili/Circle3-v1", "sili", s, paper, _const(n, 1),
                           profile="paper", name=name))  # fmt: skip
    claims = claims_table(pd.concat(parts, ignore_index=True))
    return {c.task: c for c in claims if c.claim == "package default over paper profile"}


def test_the_default_on_driving_is_decided_on_five_seeds_of_each_profile():
    from sili_robots.sweep.runner import plan

    n = 2500
    names = {
        profile: [r.name for b in blocks for r in plan(block(b).specs(("driving",)))]
        for profile, blocks in {
            "package": ("sili-oracle", "default-seeds"),
            "paper": ("paper-profile", "paper-seeds"),
        }.items()
    }
    assert len(names["package"]) == 6 + 2 and len(names["paper"]) == 3 + 2  # sili-oracle: + Oracle
    parts = []
    for profile, reward in (("package", -0.5), ("paper", -0.2)):
        for name in names[profile]:
            if "oracle" in name:
                continue
            seed = int(name.rsplit("__s", 1)[1])
            # the first three seeds alike; the two added seeds decide
            rewards = _const(n, -0.5 if seed < 3 else reward)
            parts.append(_rows("driving", "sili/Driving-v0", "sili", seed, rewards, _const(n, 1),
                               profile=profile, name=name))  # fmt: skip
    df = pd.concat(parts, ignore_index=True)
    rows = {c.task: c for c in claims_table(df) if c.claim == "package default over paper profile"}
    assert rows["driving"].verdict == NO  # -0.5 against (3 x -0.5 + 2 x -0.2) / 5 = -0.38
    assert rows["driving"].measured.startswith("5 seeds each: score package 0.50 (reward -0.50")
    four = claims_table(df[df.run != names["paper"][-1]])
    (row,) = [
        c for c in four if c.claim == "package default over paper profile" and c.task == "driving"
    ]
    assert row.verdict == "not measured yet (runs at the grid's budget: paper 4/5)"


@pytest.mark.parametrize(
    ("held", "verdict", "short_of"),
    [
        ({0.0: 0, 0.2: 0, 0.4: 1, 0.6: 1, 0.8: 1, 1.0: 0.95}, HOLDS, ""),
        ({0.0: 0, 0.2: 1, 0.4: 1, 0.6: 1, 0.8: 1, 1.0: 1}, PART, "b=0.2 stabilizes too"),
        ({0.0: 0, 0.2: 0, 0.4: 1, 0.6: 0.85, 0.8: 1, 1.0: 1}, NO, ""),
        ({0.0: 0, 0.2: 0, 0.4: 0.89, 0.6: 1, 0.8: 1, 1.0: 1}, NO, ""),
        ({0.0: 0, 0.2: 0, 0.4: 0.9, 0.6: 1, 0.8: 1, 1.0: 1}, HOLDS, ""),  # 0.9 is stable
    ],
)
def test_b_from_0_4_stabilizes_and_smaller_b_does_not(held, verdict, short_of):
    """The b figure's right panel: every b >= 0.4 holds (mean true stability >= 0.9), b < 0.4
    does not; one b >= 0.4 below 0.9 (0.85) does not hold, a small b holding too is in part."""
    parts = []
    for b, value in held.items():
        for seed in range(5):
            name = run_name("circle-3", "sili", seed, beta=b)
            parts.append(_rows("circle-3", "sili/Circle3-v1", "sili", seed, _const(1000, -10),
                               _held(1000, value), beta=b, name=name))  # fmt: skip
    claims = claims_table(pd.concat(parts))
    (claim,) = [c for c in claims if c.claim == "b >= 0.4 stabilizes"]
    assert claim.verdict == verdict, claim
    # decided from true stability alone: a version without reference bounds changes nothing
    unbounded = pd.concat(parts).assign(task_id="sili/Circle3-v9")
    assert [c for c in claims_table(unbounded) if c.claim == claim.claim] == [claim]
    assert claim.measured.startswith("true stability b=0 0.00, b=0.2 ")
    assert claim.short_of == short_of  # none but for a verdict in part
    one_short = pd.concat(parts[:-1])  # b=1 has 4 of its 5 seeds
    (claim,) = [c for c in claims_table(one_short) if c.claim == "b >= 0.4 stabilizes"]
    assert claim.verdict == "not measured yet (runs at the grid's budget: b=1 4/5)"


def _held(n: int, share: float) -> np.ndarray:
    """A run's true stability per interaction, its last 100 held in exactly ``share`` of them
    (a mean of 0.9 that is 0.9 to the last bit)."""
    last = (np.arange(100) < round(share * 100)).astype(float)
    return np.r_[_const(n - 100, share), last]


def _stability_claims(held: dict, task_ids: dict | None = None, drop: str = "") -> dict:
    """The claims of who stabilizes, from every grid run of every method on every task, each
    holding the opponent in the share ``held[(method, task)]`` of its interactions (0 unless
    given); ``task_ids``: a task's version other than its current one; ``drop``: a run left out."""
    from sili_robots.tasks import task_spec

    methods = ("sili", "oracle", "lili", "sac", "stable", "smirl")
    parts = []
    for b in ("sili-oracle", "paper-profile", "lili-sac", "stable-smirl"):
        for task in block(b).tasks:
            task_id = (task_ids or {}).get(task, task_spec(task).gym_id)

            def curve(n, share):
                return _const(n, -10.0), _held(n, share)

            curves = {m: lambda n, m=m, t=task: curve(n, held.get((m, t), 0.0)) for m in methods}
            parts += _planned_rows(b, task, task_id, curves)
    df = pd.concat(parts, ignore_index=True)
    return {(c.claim, c.task): c for c in claims_table(df[df.run != drop])}


def test_who_stabilizes_is_decided_from_true_stability():
    tasks = paper_grid.TASKS
    # SILI holds everywhere, nobody else anywhere
    claims = _stability_claims({("sili", t): 1.0 for t in tasks})
    assert claims["SILI stabilizes", "all"].verdict == HOLDS
    both = claims["SILI and Oracle stabilize", "circle-continuous"]
    assert (both.verdict, both.short_of) == (PART, "Oracle does not")
    assert both.measured == "true stability SILI 1.00, Oracle 0.00"
    assert claims["only SILI stabilizes", "circle-unequal"].verdict == HOLDS
    assert claims["SMiRL does not stabilize consistently", "all"].verdict == HOLDS
    # SILI not on Driving (its paper-profile runs) and Sawyer-Reach; Oracle on Circle
    # (Continuous); LILI on Circle (Unequal); SMiRL on four of the seven tasks
    held = {("sili", t): 1.0 for t in tasks if t not in ("driving", "sawyer-reach")}
    held |= {("oracle", "circle-continuous"): 0.9, ("lili", "circle-unequal"): 1.0}  # 0.9: holds
    held |= {("smirl", t): 1.0 for t in tasks[:4]}
    claims = _stability_claims(held)
    sili = claims["SILI stabilizes", "all"]
    assert (sili.verdict, sili.short_of) == (PART, "not on driving or sawyer-reach")
    assert "driving 0.00, sawyer-reach 0.00" in sili.measured
    assert claims["SILI and Oracle stabilize", "circle-continuous"].verdict == HOLDS
    only = claims["only SILI stabilizes", "circle-unequal"]
    assert (only.verdict, only.short_of) == (PART, "LILI and SMiRL stabilize too")
    smirl = claims["SMiRL does not stabilize consistently", "all"]
    assert smirl.verdict == PART and smirl.short_of.startswith("stabilizes on circle-3, circle-8")
    # SMiRL holds on three tasks, not on four: more than half; Oracle too on Circle (Unequal)
    held = {("sili", t): 1.0 for t in tasks} | {("smirl", t): 1.0 for t in tasks[4:]}
    claims = _stability_claims(held | {("oracle", "circle-unequal"): 0.89})
    assert claims["SMiRL does not stabilize consistently", "all"].verdict == HOLDS
    assert claims["only SILI stabilizes", "circle-unequal"].verdict == HOLDS
    claims = _stability_claims(held | {("oracle", "circle-unequal"): 0.9})
    only = claims["only SILI stabilizes", "circle-unequal"]
    assert (only.verdict, only.short_of) == (PART, "Oracle stabilizes too")
    # nobody holds anywhere, then only SMiRL, everywhere
    claims = _stability_claims({})
    assert claims["SILI stabilizes", "all"].verdict == NO
    assert claims["SILI and Oracle stabilize", "circle-continuous"].verdict == NO
    only = claims["only SILI stabilizes", "circle-unequal"]
    assert (only.verdict, only.short_of) == (PART, "SILI does not stabilize")
    claims = _stability_claims({("smirl", t): 1.0 for t in tasks})
    assert claims["only SILI stabilizes", "circle-unequal"].verdict == NO
    assert claims["SMiRL does not stabilize consistently", "all"].verdict == NO


def test_who_stabilizes_needs_every_run_but_no_reference_bounds():
    held = {("sili", "circle-unequal"): 1.0}
    claims = _stability_claims(held, task_ids={"circle-unequal": "sili/CircleUnequal-v9"})
    assert claims["only SILI stabilizes", "circle-unequal"].verdict == HOLDS
    comparable = claims["SILI comparable to Oracle", "circle-unequal"].verdict
    assert comparable.startswith("not measured yet (no reference bounds for sili/CircleUnequal-v9")
    claims = _stability_claims(held, drop=run_name("driving", "smirl", 1, beta=0.5))
    smirl = claims["SMiRL does not stabilize consistently", "all"]
    assert smirl.verdict == "not measured yet (runs at the grid's budget: SMiRL on driving 2/3)"
    assert claims["only SILI stabilizes", "circle-unequal"].verdict == HOLDS


def test_first_finished_run_finals():
    """A run's final numbers are means over its last 100 interactions, as the table says."""
    df = _rows(
        "circle-3",
        "sili/Circle3-v1",
        "sili",
        0,
        np.r_[_const(100, -50), _const(50, -10), _const(50, -4)],
        np.r_[_const(60, 0), _const(140, 1)],
    )
    (row,) = run_finals(df).itertuples()
    assert row.task_reward == pytest.approx(-7.0) and row.stability == 1.0
    assert row.first_stable == 55  # the first 50-window with >= 0.9 (45 of 50 stable) starts at 55


def test_claims_write_replaces_the_readme_block(sweep_and_collection, tmp_path, capsys):
    _, collection = sweep_and_collection  # tiny runs: they measure no claim
    readme = tmp_path / "README.md"
    readme.write_text(f"# x\n{START}\nstale-table\n{END}\ntail\n")
    assert main(["claims", str(collection), "--write", str(readme)]) == 2
    printed = capsys.readouterr()
    assert "measures none of the claims" in printed.err and printed.out == ""  # no table
    assert "stale-table" in readme.read_text()  # a table of "not measured yet" replaces nothing
    assert main(["claims", str(collection)]) == 0  # the table, and why it is empty
    printed = capsys.readouterr()
    assert "| not measured yet" in printed.out
    assert "measures none of the claims: each judges only runs finished at" in printed.err
    committed = Path(__file__).resolve().parents[1] / "results" / "paper-grid"
    assert main(["claims", str(committed), "--write", str(readme)]) == 0
    table = capsys.readouterr().out
    assert main(["claims", str(committed)]) == 0
    printed = capsys.readouterr()
    assert printed.out == table and "measures none" not in printed.err  # the grid's: no note
    text = readme.read_text()
    assert text.startswith(f"# x\n{START}\n| claim |") and text.endswith(f"{END}\ntail\n")
    assert table in text and "stale-table" not in text
    # part of the grid (Circle 3's runs alone) would undo the decided rows of other tasks
    part = tmp_path / "part"
    for run in (committed / "runs").glob("circle-3__*"):
        shutil.copytree(run, part / "runs" / run.name)
    assert main(["claims", str(part), "--write", str(readme)]) == 2
    printed = capsys.readouterr()
    assert "would replace rows it shows decided with 'not measured yet'" in printed.err
    assert "SILI comparable to Oracle on circle-8: not measured yet (runs at" in printed.err
    assert printed.out == ""
    assert readme.read_text() == text
    readme.write_text("no block")
    assert main(["claims", str(committed), "--write", str(readme)]) == 2


def test_the_b_sweep_pools_only_constant_b_runs_of_the_sweeps_length():
    from sili_robots.plot_data import b_sweep_rows, curve_rows, variant_labels

    def run(beta, n, name, scheduled=False, profile="package"):
        rows = _rows("circle-3", "sili/Circle3-v1", "sili", 0, _const(n, -5), _const(n, 1),
                     profile=profile, beta=beta, name=name)  # fmt: skip
        return rows.assign(beta_scheduled=scheduled, controller="", latent="discrete")

    df = pd.concat(
        [
            run(0.0, 1000, "b0"),
            run(0.5, 1000, "b0.5"),
            run(1.0, 1000, "b1"),
            run(0.5, 2000, "long"),  # the grid's SILI at another budget
            run(0.5, 2000, "scheduled", scheduled=True),
            run(0.5, 1000, "paper", profile="paper"),
        ],
        ignore_index=True,
    )
    assert sorted(b_sweep_rows(df, "circle-3")["run"].unique()) == ["b0", "b0.5", "b1"]
    labels = dict(zip(df["run"], variant_labels(df), strict=True))
    assert (
        labels["scheduled"] == "SILI (package) b→0.5" and labels["b0.5"] == "SILI (package) b=0.5"
    )
    assert labels["paper"] == "SILI (paper)"
    alone = df[df.profile == "package"]  # one profile: not named
    assert set(variant_labels(alone)) == {"SILI b→0.5", "SILI b=0", "SILI b=0.5", "SILI b=1"}
    # the task's learning curves leave the b sweep to its own figure, but draw a lone b sweep
    assert sorted(curve_rows(df, "circle-3")["run"].unique()) == ["long", "paper", "scheduled"]
    alone = df[df.run.isin(["b0", "b0.5", "b1"])]
    assert sorted(curve_rows(alone, "circle-3")["run"].unique()) == ["b0", "b0.5", "b1"]


def test_a_resumed_grid_plans_each_block_as_it_was_recorded(tmp_path):
    from sili_robots.commands.grid import recorded
    from sili_robots.sweep.state import record_invocation

    (fresh,) = block("sili-oracle").specs(("circle-8",))
    older = fresh.to_dict()
    older["agent_overrides"]["model.updates_per_interaction"] = 20  # a default since changed
    record_invocation(tmp_path, SweepSpec.from_dict(older))
    again = recorded(tmp_path, fresh)
    assert again.agent_overrides["model.updates_per_interaction"] == 20
    (other,) = block("lili-sac").specs(("circle-8",))
    assert recorded(tmp_path, other) is other  # not recorded yet: planned anew


def test_a_grid_with_a_failed_run_names_it_with_its_error_as_a_sweep_does(
    tmp_path, monkeypatch, capsys
):
    """stdout holds JSON lines alone, the failures as the sweep's ``failed`` (run -> error):
    the grid printed prose there, and its failures as a bare list of names."""
    import sili_robots.sweep as sweep_module
    from sili_robots import paper_grid
    from sili_robots.sweep.worker import Outcome

    real = sweep_module.run_sweep

    def one_fails(*args, **kwargs):
        report = real(*args, **kwargs)
        report.outcomes["extra__s9"] = Outcome("extra__s9", "failed", error="ValueError: boom")
        return report

    tiny = paper_grid.Block("tiny", ("sac",), ("circle-3",), seeds=(0,), interactions=3)
    monkeypatch.setattr(paper_grid, "BLOCKS", (tiny,))
    monkeypatch.setattr(sweep_module, "run_sweep", one_fails)
    args = ["grid", "--blocks", "tiny", "--workers", "1", "--into", str(tmp_path / "c")]
    assert main([*args, "--sweep-dir", str(tmp_path / "s")]) == 1
    lines = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    assert lines[-1] == {"failed": {"extra__s9": "ValueError: boom"}}


def test_a_fresh_clone_resumes_the_grid_from_its_collection(tmp_path, monkeypatch, capsys):
    """Without its sweep directory (a fresh clone) ``sili grid`` counts the collected runs as
    done, even on a machine that would choose another kernel library, and trains only the
    rest; with every run collected it trains nothing."""
    from dataclasses import replace

    import sili_robots.sweep.spec as spec_module
    from sili_robots import paper_grid

    tiny = paper_grid.Block("tiny", ("sili",), ("circle-3",), seeds=(0,), interactions=3)
    monkeypatch.setattr(paper_grid, "BLOCKS", (tiny,))
    collection = tmp_path / "collection"
    args = ["grid", "--blocks", "tiny", "--workers", "1", "--into", str(collection)]
    assert main([*args, "--sweep-dir", str(tmp_path / "first")]) == 0
    (first,) = (collection / "runs").iterdir()
    matmul = json.loads((first / "config.json").read_text())["run"]["agent"]["matmul"]
    other = "aten" if matmul == "onednn" else "onednn"
    monkeypatch.setattr(spec_module, "default_matmul", lambda: other)
    monkeypatch.setattr(paper_grid, "BLOCKS", (replace(tiny, seeds=(0, 1)),))
    capsys.readouterr()
    assert main([*args, "--sweep-dir", str(tmp_path / "fresh")]) == 0
    second = first.name.replace("__s0", "__s1")
    printed = capsys.readouterr()
    assert f'"collected": ["{second}"]' in printed.out  # seed 0 not trained again
    assert [json.loads(line) for line in printed.out.splitlines()]  # JSON lines alone
    assert "grid: " in printed.err
    restored = tmp_path / "fresh" / "runs" / first.name
    assert sorted(p.name for p in restored.iterdir()) == [
        "config.json",
        "metrics.csv.gz",
        "summary.json",
    ]
    added = json.loads((collection / "runs" / second / "config.json").read_text())
    assert added["run"]["agent"]["matmul"] == matmul  # the block's, not this machine's
    assert main([*args, "--sweep-dir", str(tmp_path / "third")]) == 0
    assert "all 2 runs collected" in capsys.readouterr().err
    assert not (tmp_path / "third").exists()


def test_a_damaged_summary_or_config_is_named_not_a_traceback(
    sweep_and_collection, tmp_path, capsys
):
    sweep, _ = sweep_and_collection
    source = tmp_path / "sweep"
    shutil.copytree(sweep, source)
    run = source / "runs" / "circle-3__sili-bschedule__s0"
    (run / "summary.json").write_text("")  # a full disk, say
    assert main(["runs", str(source)]) == 2
    err = capsys.readouterr().err
    assert f"{run / 'summary.json'} is damaged" in err and "delete it, then resume the run" in err
    (run / "summary.json").write_text("{}")  # well-formed, but not a summary
    assert main(["runs", str(source)]) == 2
    assert "is damaged (no final_task_reward" in capsys.readouterr().err
    (run / "config.json").write_text("{")
    assert main(["sweep", "--resume", str(source), "--dry-run"]) == 2
    assert f"{run / 'config.json'} is damaged" in capsys.readouterr().err


def test_every_damaged_run_is_named_at_once(sweep_and_collection, tmp_path, capsys):
    """A long sweep's damaged runs are mended in one go: the tables and collect name them all,
    not the first alone, and collect copies nothing."""
    sweep, _ = sweep_and_collection
    source = tmp_path / "sweep"
    shutil.copytree(sweep, source)
    summary = source / "runs" / "circle-3__sili-bschedule__s0" / "summary.json"
    config = source / "runs" / "circle-3__sili-paper-b0.5__s0" / "config.json"
    summary.write_text("")
    config.write_text("{")
    into = tmp_path / "into"
    for args in (["runs", str(source)], ["collect", str(source), "--into", str(into)]):
        assert main(args) == 2
        err = capsys.readouterr().err
        assert "2 runs cannot be read:" in err, err
        assert f"\n  {summary} is damaged" in err and f"\n  {config} is damaged" in err
    assert not into.exists()


def test_collect_replaces_a_damaged_copy_and_never_copies_a_damaged_run(
    sweep_and_collection, tmp_path, capsys
):
    sweep, collection = sweep_and_collection
    mine = tmp_path / "collection"
    shutil.copytree(collection, mine)
    name = "circle-3__sili-bschedule__s0"
    gz = mine / "runs" / name / "metrics.csv.gz"
    whole = gz.read_bytes()
    gz.write_bytes(whole[: len(whole) // 2])  # cut: the plot names it, "collect it again"
    assert main(["plot", str(mine), "--out", str(tmp_path / "fig")]) == 2
    assert f"{gz} is damaged" in capsys.readouterr().err
    assert main(["collect", str(sweep), "--into", str(mine)]) == 0
    assert json.loads(capsys.readouterr().out)["replaced"] == [name]
    assert gz.read_bytes() == whole
    config = mine / "runs" / name / "config.json"
    intact = config.read_text()
    config.write_text(json.dumps({"run": {"task": "circle-3"}}))  # a hand-edited copy
    assert main(["collect", str(sweep), "--into", str(mine)]) == 0
    assert json.loads(capsys.readouterr().out)["replaced"] == [name]
    assert config.read_text() == intact
    # a damaged source is named and nothing is copied from it
    source = tmp_path / "source"
    shutil.copytree(sweep, source)
    run = source / "runs" / name
    lines = (run / "metrics.csv").read_text().splitlines(keepends=True)
    (run / "metrics.csv").write_text("".join(lines[:-2]))  # rows lost at a row boundary
    into = tmp_path / "into"
    assert main(["collect", str(source), "--into", str(into)]) == 2
    err = capsys.readouterr().err
    assert f"{run / 'metrics.csv'} is damaged (it holds 4 rows, its summary.json says 6)" in err
    assert not (into / "runs").exists()
    (run / "metrics.csv").write_text("".join(lines))
    summary = json.loads((run / "summary.json").read_text())
    (run / "summary.json").write_text(json.dumps({**summary, "interactions": "abc"}))
    assert main(["collect", str(source), "--into", str(into)]) == 2
    assert "is damaged (interactions 'abc' is not a count)" in capsys.readouterr().err
    (run / "summary.json").write_text(json.dumps({**summary, "final_task_reward": "abc"}))
    assert main(["collect", str(source), "--into", str(into)]) == 2  # which every table refuses
    assert "summary.json is damaged (a value of final_task_reward" in capsys.readouterr().err
    assert not (into / "runs").exists()
    (run / "summary.json").write_text(json.dumps(summary))
    config = json.loads((run / "config.json").read_text())
    del config["run"]["agent"]
    (run / "config.json").write_text(json.dumps(config))
    for args in (["collect", str(source), "--into", str(into)], ["claims", str(source)]):
        assert main(args) == 2
        assert f"{run / 'config.json'} is damaged (no 'agent')" in capsys.readouterr().err
    (run / "config.json").write_text(json.dumps({"run": 5}))
    assert main(["collect", str(source), "--into", str(into)]) == 2
    assert f"{run / 'config.json'} is damaged" in capsys.readouterr().err
    assert not (into / "runs").exists()


def test_a_rehearsal_at_a_fraction_of_the_budgets_goes_into_folders_of_its_own(
    tmp_path, monkeypatch, capsys
):
    assert block("stable-smirl").scaled(0.01).budget("driving") == 12  # 2,500 x 0.5 x 0.01
    assert block("b-sweep").scaled(0.01).budget("circle-3") == 10  # its own 1,000
    assert block("sili-oracle").scaled(1e-6).budget("circle-3") == 1  # never 0
    monkeypatch.chdir(Path(__file__).resolve().parents[1])  # where the defaults are the grid's
    assert main(["grid", "--fraction", "0.01", "--dry-run"]) == 2
    assert "goes into a --sweep-dir of its own, not sweeps/paper-grid" in capsys.readouterr().err
    for bad, said in (
        ("0", "0.0 is outside the allowed range (0, 1]"),
        ("-0.5", "-0.5 is outside the allowed range (0, 1]"),
        ("nan", "nan is outside the allowed range (0, 1]"),
    ):
        with pytest.raises(SystemExit) as exc:
            main(["grid", "--fraction", bad, "--dry-run", "--sweep-dir", str(tmp_path)])
        assert exc.value.code == 2 and said in capsys.readouterr().err
    own = ["--sweep-dir", str(tmp_path / "s"), "--into", str(tmp_path / "r")]
    assert main(["grid", "--fraction", "0.01", "--dry-run", "--blocks", "b-sweep", *own]) == 0
    out = capsys.readouterr().out
    assert "b-sweep on circle-3 (10 interactions): 30 runs, 0 done" in out
    assert "neither exists here" not in out  # the folders given are new: nothing to hint
    assert main(["grid", "--dry-run", "--blocks", "b-sweep"]) == 0  # the defaults, from here
    monkeypatch.chdir(tmp_path)
    assert main(["grid", "--dry-run", "--blocks", "b-sweep"]) == 0  # the defaults, not here
    assert "neither exists here; run from the repository root" in capsys.readouterr().out
    repository = Path(__file__).resolve().parents[1]  # the grid's own folders, from elsewhere
    grid_own = ["--sweep-dir", str(repository / "sweeps" / "paper-grid"), "--into", str(tmp_path)]
    assert main(["grid", "--fraction", "0.01", "--dry-run", *grid_own]) == 2
    assert "goes into a --sweep-dir of its own, not " in capsys.readouterr().err
    # a rehearsal folder holding runs at another budget: refused before anything trains
    held = tmp_path / "s" / "runs" / "circle-3__sili-b0__s0"
    held.mkdir(parents=True)
    (held / "config.json").write_text(json.dumps({"run": {"interactions": 5}}))
    assert main(["grid", "--fraction", "0.01", "--blocks", "b-sweep", *own]) == 2
    assert (
        "holds circle-3__sili-b0__s0 at 5 interactions where this grid (--fraction 0.01) plans 10"
        in capsys.readouterr().err
    )
    assert sorted(p.name for p in (tmp_path / "s" / "runs").iterdir()) == [held.name]


def test_collect_refuses_a_run_one_row_short(sweep_and_collection, tmp_path, capsys):
    sweep, _ = sweep_and_collection
    source = tmp_path / "source"
    shutil.copytree(sweep, source)
    metrics = source / "runs" / "circle-3__sili-bschedule__s0" / "metrics.csv"
    metrics.write_text("".join(metrics.read_text().splitlines(keepends=True)[:-1]))
    assert main(["collect", str(source), "--into", str(tmp_path / "into")]) == 2
    assert "is damaged (it holds 5 rows, its summary.json says 6)" in capsys.readouterr().err


def test_a_collected_run_replaces_a_training_there_stopped_before_its_summary(
    sweep_and_collection, tmp_path
):
    """All its rows logged, no summary.json: it is not further than the collected copy."""
    from sili_robots.sweep.collect import collect

    sweep, collection = sweep_and_collection
    name = "circle-3__sili-bschedule__s0"
    into = tmp_path / "sweep"
    shutil.copytree(sweep, into)
    (into / "runs" / name / "summary.json").unlink()
    assert collect([collection], into, names=[name]).replaced == [name]
    assert (into / "runs" / name / "summary.json").is_file()


def test_grid_refuses_a_sweep_folder_holding_a_run_at_a_larger_budget(
    tmp_path, monkeypatch, capsys
):
    import sili_robots.sweep as sweep_package

    monkeypatch.setattr(sweep_package, "run_sweep", lambda *a, **k: pytest.fail("trained"))
    own = ["--sweep-dir", str(tmp_path / "s"), "--into", str(tmp_path / "r")]
    held = tmp_path / "s" / "runs" / "circle-3__sili-b0__s0"
    held.mkdir(parents=True)
    (held / "config.json").write_text(json.dumps({"run": {"interactions": 50}}))
    assert main(["grid", "--fraction", "0.01", "--blocks", "b-sweep", *own]) == 2
    assert "holds circle-3__sili-b0__s0 at 50 interactions" in capsys.readouterr().err


def test_a_block_recorded_at_another_budget_is_not_the_block_resumed(tmp_path):
    """A rehearsal's invocation (--fraction) in the folder does not set the full grid's budget."""
    from sili_robots.commands.grid import recorded
    from sili_robots.sweep.state import record_invocation

    (full,) = block("sili-oracle").specs(("circle-8",))
    (rehearsal,) = block("sili-oracle").scaled(0.01).specs(("circle-8",))
    record_invocation(tmp_path, rehearsal)
    assert recorded(tmp_path, full).interactions == full.interactions


def test_a_wrong_write_file_is_named_before_the_results_are_read(tmp_path):
    """``sili claims DIR --write FILE`` names a wrong FILE before it reads DIR's results."""
    empty = tmp_path / "results"  # holds no runs: reading it would fail too
    empty.mkdir()
    missing = tmp_path / "README.md"
    out = sili("claims", empty, "--write", missing)
    assert out.returncode == 2 and out.stdout == ""
    assert f"--write {missing}: no such file" in out.stderr and "holds no runs" not in out.stderr
    missing.write_text("# no claims block here\n", encoding="utf-8")
    out = sili("claims", empty, "--write", missing)
    assert out.returncode == 2
    assert f"no {START} ... {END} block" in out.stderr and "holds no runs" not in out.stderr


def test_write_replaces_the_first_block_and_leaves_a_later_mention_of_the_markers(tmp_path):
    """``sili claims --write`` replaces the file's claims block, and only that one."""
    readme = tmp_path / "README.md"
    note = f"`sili claims --write` fills the table between {START} and {END} above.\n"
    readme.write_text(f"# Results\n{START}\nold table\n{END}\n\n{note}", encoding="utf-8")
    write_block(readme, "| new | table |\n")
    assert readme.read_text(encoding="utf-8") == (
        f"# Results\n{START}\n| new | table |\n{END}\n\n{note}"
    )


def test_a_collected_run_longer_than_the_budget_is_not_done(tmp_path, monkeypatch):
    """A grid run counts as done only at its block's budget: a collected run of the same name
    that trained longer (extended by hand) is not the block's run."""
    tiny = paper_grid.Block("tiny", ("sili",), ("circle-3",), seeds=(0,), interactions=3)
    monkeypatch.setattr(paper_grid, "BLOCKS", (tiny,))
    (run,) = plan(tiny.specs(("circle-3",)))
    collection = tmp_path / "collection"
    args = ["grid", "--dry-run", "--blocks", "tiny", "--tasks", "circle-3"]
    args += ["--sweep-dir", tmp_path / "sweep", "--into", collection]
    for trained, done in ((3, 1), (4, 0), (2, 0)):
        folder = run_path(collection, run.name)
        folder.mkdir(parents=True, exist_ok=True)
        (folder / SUMMARY).write_text(json.dumps({"interactions": trained}))
        out = sili(*args)
        assert out.returncode == 0, out.stderr
        assert f"tiny on circle-3 (3 interactions): 1 run, {done} done" in out.stdout


@pytest.mark.parametrize("present", ["results/paper-grid", "sweeps/paper-grid"])
def test_grid_goes_on_where_one_of_its_default_folders_exists(tmp_path, monkeypatch, present):
    """``sili grid`` with its default folders runs where either of them exists (a fresh clone
    has the collection but no sweep directory), and is refused only where neither does."""
    (tmp_path / present).mkdir(parents=True)
    monkeypatch.chdir(tmp_path)
    # a selection that runs nothing: refused for that, after the folders were accepted
    out = sili("grid", "--blocks", "b-sweep", "--tasks", "circle-8", "--workers", 1)
    assert out.returncode == 2
    assert "neither sweeps/paper-grid nor results/paper-grid exists" not in out.stderr
    assert "b-sweep run nothing on circle-8" in out.stderr
    out = sili("grid", "--dry-run", "--blocks", "b-sweep", "--tasks", "circle-3")
    assert out.returncode == 0 and "neither exists here" not in out.stdout


@pytest.mark.parametrize("option", ["--sweep-dir", "--into"])
def test_an_unwritable_folder_stops_a_grid_but_not_its_listing(tmp_path, monkeypatch, option):
    """``sili grid`` checks that it can write its folders before it trains, and a ``--dry-run``
    listing, which writes nothing, does not ask for that."""
    import sili_robots.sweep as sweep

    tiny = paper_grid.Block("tiny", ("sac",), ("circle-3",), seeds=(0,), interactions=2)
    monkeypatch.setattr(paper_grid, "BLOCKS", (tiny,))

    def trains(*args, **kwargs):
        raise AssertionError("the grid trained before it checked its folders")

    monkeypatch.setattr(sweep, "run_sweep", trains)
    a_file = tmp_path / "file"
    a_file.write_text("x")
    folders = {"--sweep-dir": tmp_path / "sweep", "--into": tmp_path / "collection"}
    folders[option] = a_file / "sub"  # under a file: nothing can be written there
    args = ["grid", "--blocks", "tiny", "--tasks", "circle-3", "--workers", 1]
    args += [x for pair in folders.items() for x in pair]
    out = sili(*args)
    assert out.returncode == 2 and f"{option} {a_file / 'sub'}: cannot write there" in out.stderr
    listing = sili(*args, "--dry-run")
    assert listing.returncode == 0, listing.stderr
    assert "tiny on circle-3 (2 interactions): 1 run, 0 done" in listing.stdout


def test_a_tiny_rehearsal_of_the_b_sweep_still_runs_one_interaction(tmp_path, capsys):
    """A block with its own interaction count (the b sweep) scaled by a tiny --fraction never
    plans 0 interactions."""
    assert block("b-sweep").scaled(1e-6).budget("circle-3") == 1
    own = ["--sweep-dir", str(tmp_path / "s"), "--into", str(tmp_path / "r")]
    assert main(["grid", "--fraction", "0.0001", "--dry-run", "--blocks", "b-sweep", *own]) == 0
    assert "b-sweep on circle-3 (1 interaction): 30 runs, 0 done" in capsys.readouterr().out


def test_grid_refuses_a_file_as_its_sweep_dir_in_a_dry_run_too(tmp_path, capsys):
    """A dry run said nothing of --sweep-dir being a file (exit 0); the grid itself then fails."""
    mine = tmp_path / "notes.txt"
    mine.write_text("mine\n")
    grid = ["grid", "--tasks", "circle-3", "--blocks", "sili-oracle", "--dry-run"]
    assert main([*grid, "--sweep-dir", str(mine), "--into", str(tmp_path / "c")]) == 2
    assert f"--sweep-dir {mine} is a file; give a directory" in capsys.readouterr().err
    assert mine.read_text() == "mine\n" and not (tmp_path / "c").exists()
