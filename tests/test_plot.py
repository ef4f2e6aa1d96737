"""``sili plot``: the figures show exactly the sweep's results table (read back from the figure
objects), and the command writes readable PNG and PDF files."""

import inspect
import json
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from fast_settings import FAST_AGENT as FAST
from matplotlib.collections import PolyCollection
from matplotlib.colors import to_rgb

from sili_robots.cli import main
from sili_robots.plot_data import b_sweep_rows, default_smoothing, load_results
from sili_robots.plotting import (
    METHOD_COLORS,
    NO_STABILITY_TERM,
    beta_sweep,
    learning_curves,
    overview,
)
from sili_robots.sweep import LocalBackend, SweepSpec, run_sweep


@pytest.fixture(scope="module")
def sweep_dir(tmp_path_factory):
    """Circle (3 Goals): SILI at b = 0.5 and 1 and SAC, 2 seeds; SAC on Speaker-Listener."""
    out = tmp_path_factory.mktemp("plot-sweep")
    common = {"seeds": [0, 1], "interactions": 8, "agent_overrides": FAST, "checkpoint_every": 4}
    specs = [
        SweepSpec(tasks=["circle-3"], methods=["sili", "sac"], betas=[0.5, 1.0], **common),
        SweepSpec(tasks=["speaker-listener"], methods=["sac"], **{**common, "seeds": [0]}),
    ]
    report = run_sweep(specs, out, LocalBackend(workers=2), progress=False)
    assert report.ok, report.failed
    return out


def _moving_average(x: np.ndarray, w: int) -> np.ndarray:
    """Trailing mean over the last w values that are there (fewer at the start; NaN where none
    is), written independently."""
    x = x.astype(float)
    out = [x[max(i - w + 1, 0) : i + 1] for i in range(len(x))]
    return np.array([np.nanmean(v) if np.isfinite(v).any() else np.nan for v in out])


def _expected_curve(table, task, method, beta, column, w):
    rows = table[(table.task == task) & (table.method == method) & (table.config_beta == beta)]
    per_seed = np.stack(
        [
            _moving_average(g.sort_values("interaction")[column].to_numpy(), w)
            for _, g in rows.groupby("seed")
        ]
    )
    return per_seed.mean(axis=0), per_seed.std(axis=0)


def _line(ax, label):
    (line,) = [ln for ln in ax.get_lines() if ln.get_label() == label]
    return line


def _band(ax, line):
    """The shaded band drawn in the colour of ``line``."""
    color = to_rgb(line.get_color())
    (band,) = [
        c
        for c in ax.collections
        if isinstance(c, PolyCollection) and np.allclose(c.get_facecolor()[0][:3], color)
    ]
    return band


def test_learning_curves_plot_the_table_mean_and_std_across_seeds(sweep_dir):
    table = pd.read_csv(sweep_dir / "results.csv")
    # true stability, derived here independently: none for the game's first interaction
    table["stable"] = (1 - table["strategy_changed"]).where(table["interaction"] > 0)
    fig = learning_curves(load_results(sweep_dir), "circle-3", smooth=3)
    axes = {ax.get_gid(): ax for ax in fig.axes}
    assert set(axes) == {"task_reward", "true_stability", "stability_reward"}
    variants = {"SILI b=0.5": ("sili", 0.5), "SILI b=1": ("sili", 1.0), "SAC": ("sac", 0.0)}
    columns = {"task_reward": "task_reward", "true_stability": "stable"}
    for metric, ax in axes.items():
        # SAC has no latent: no stability term drawn for it (it read as a perfect 0)
        shown = {k: v for k, v in variants.items() if metric != "stability_reward" or k != "SAC"}
        assert {ln.get_label() for ln in ax.get_lines()} == set(shown)
        for label, (method, beta) in shown.items():
            column = columns.get(metric, metric)
            mean, std = _expected_curve(table, "circle-3", method, beta, column, 3)
            line = _line(ax, label)
            xy = line.get_xydata()
            first = 1 if metric == "true_stability" else 0  # interaction 0 kept nothing
            np.testing.assert_array_equal(xy[:, 0], np.arange(first, 8))
            np.testing.assert_allclose(xy[:, 1], mean[first:], rtol=1e-9, atol=1e-12)
            # the band of this variant spans mean - std .. mean + std at every interaction,
            # clipped to [0, 1] for true stability, a fraction
            low, high = (0.0, 1.0) if metric == "true_stability" else (-np.inf, np.inf)
            verts = np.concatenate([p.vertices for p in _band(ax, line).get_paths()])
            for x in range(first, 8):
                at_x = verts[np.isclose(verts[:, 0], x), 1]
                assert at_x.min() == pytest.approx(max(mean[x] - std[x], low), abs=1e-9)
                assert at_x.max() == pytest.approx(min(mean[x] + std[x], high), abs=1e-9)


def test_beta_figure_plots_final_values_against_b(sweep_dir, monkeypatch):
    table = pd.read_csv(sweep_dir / "results.csv")
    monkeypatch.setitem(METHOD_COLORS, "sili", "#123456")  # a colour no cycle would pick
    fig = beta_sweep(load_results(sweep_dir), "circle-3", window=4)
    axes = {ax.get_gid(): ax for ax in fig.axes}
    sili = table[(table.task == "circle-3") & (table.method == "sili")]
    for metric in ("task_reward", "true_stability"):
        finals = (
            sili.sort_values("interaction")
            .groupby(["config_beta", "seed"])[metric]
            .apply(lambda s: s.tail(4).mean())
            .unstack("seed")
        )
        line = _line(axes[metric], "SILI")
        xy = line.get_xydata()
        np.testing.assert_array_equal(xy[:, 0], [0.5, 1.0])
        # the method's colour, as in every figure (it took the next of matplotlib's cycle)
        assert to_rgb(line.get_color()) == to_rgb(METHOD_COLORS["sili"])
        np.testing.assert_allclose(xy[:, 1], finals.mean(axis=1).to_numpy())
        assert axes[metric].get_xlabel() == "stability weight b"


def test_beta_figure_error_bars_stay_within_a_fractions_range():
    """The grid's b sweep: b = 0.4 holds 0.994 +- 0.012, b = 0 0.062 +- 0.077 (mean +- std of
    true stability), whose bars would reach past 1 and below 0."""
    committed = Path(__file__).resolve().parents[1] / "results" / "paper-grid"
    df = load_results(committed)
    fig = beta_sweep(df[df.run.str.startswith("circle-3__sili-b")], "circle-3")
    axes = {ax.get_gid(): ax for ax in fig.axes}
    (bars,) = [c for c in axes["true_stability"].collections if c.get_segments()]
    ends = np.concatenate([s[:, 1] for s in bars.get_segments()])
    assert ends.min() == 0.0 and ends.max() == 1.0
    (rewards,) = [c for c in axes["task_reward"].collections if c.get_segments()]
    assert np.concatenate([s[:, 1] for s in rewards.get_segments()]).min() < -20  # not clipped


def test_overview_has_a_row_per_task(sweep_dir):
    fig = overview(load_results(sweep_dir), smooth=2)
    grid = [ax for ax in fig.axes if ax.get_gid()]
    assert [ax.get_gid() for ax in grid] == ["task_reward", "true_stability"] * 2
    assert [ax.get_title(loc="left") for ax in grid[::2]] == [
        "Circle (3 Goals)",
        "Detour Speaker-Listener",
    ]
    table = pd.read_csv(sweep_dir / "results.csv")
    sl = table[table.task == "speaker-listener"].sort_values("interaction")
    xy = _line(grid[2], "SAC").get_xydata()
    np.testing.assert_allclose(xy[:, 1], _moving_average(sl["task_reward"].to_numpy(), 2))


def test_plot_command_writes_png_and_pdf(sweep_dir, tmp_path, capsys):
    out = tmp_path / "figs"
    assert main(["plot", str(sweep_dir), "--out", str(out)]) == 0
    written = capsys.readouterr().out.split()
    names = sorted(p.rsplit("/", 1)[-1] for p in written)
    expected = ["circle-3", "circle-3_beta", "overview", "speaker-listener"]
    assert names == sorted(f"{n}.{ext}" for n in expected for ext in ("png", "pdf"))
    for name in expected:
        png, pdf = (out / f"{name}.png").read_bytes(), (out / f"{name}.pdf").read_bytes()
        assert png.startswith(b"\x89PNG") and len(png) > 20_000
        assert pdf.startswith(b"%PDF") and len(pdf) > 5_000


def test_plot_tasks_draws_only_their_figures(sweep_dir, tmp_path, capsys):
    out = tmp_path / "figs"
    args = ["plot", str(sweep_dir), "--out", str(out), "--formats", "png"]
    assert main([*args, "--tasks", "speaker-listener"]) == 0
    assert capsys.readouterr().out.split() == [str(out / "speaker-listener.png")]  # no overview
    assert main([*args, "--tasks", "driving"]) == 2
    err = capsys.readouterr().err
    assert "task 'driving' has no runs in" in err and "its tasks: circle-3, speaker-listener" in err
    assert main([*args, "--tasks", ","]) == 2
    assert "--tasks ',' names none" in capsys.readouterr().err
    assert main([*args, "--tasks", "sili/SpeakerListener-v1"]) == 0  # its gymnasium id, the same
    assert capsys.readouterr().out.split() == [str(out / "speaker-listener.png")]


def test_a_format_named_twice_is_written_and_listed_once(sweep_dir, tmp_path, capsys):
    """`--formats png,png` writes each figure once and lists each path once."""
    out = tmp_path / "figs"
    args = ["plot", str(sweep_dir), "--out", str(out), "--formats", "png, png"]
    assert main([*args, "--tasks", "speaker-listener"]) == 0
    assert capsys.readouterr().out.split() == [str(out / "speaker-listener.png")]


def test_plot_window_sets_the_b_sweeps_final_window(sweep_dir, tmp_path, capsys, monkeypatch):
    """`sili plot --window N` takes the b-sweep figure's final values over the last N
    interactions (100 by default); what a window computes is checked above."""
    from sili_robots import plotting

    windows = []

    def final_values(rows, window):
        windows.append(window)
        return real(rows, window)

    real = plotting.final_values
    monkeypatch.setattr(plotting, "final_values", final_values)
    args = ["plot", str(sweep_dir), "--formats", "png", "--tasks", "circle-3", "--out"]
    assert main([*args, str(tmp_path / "a")]) == 0
    assert main([*args, str(tmp_path / "b"), "--window", "2"]) == 0
    capsys.readouterr()
    assert windows == [100, 2]


def test_plot_smooth_sets_every_curves_window(sweep_dir, tmp_path, capsys, monkeypatch):
    """`sili plot --smooth N` smooths the learning curves and the overview over N interactions
    (by default a window that suits the run's length)."""
    from sili_robots import plotting

    asked = []

    def spy(real):
        def called(*args, **kwargs):
            smooth = inspect.signature(real).bind(*args, **kwargs).arguments.get("smooth")
            asked.append((real.__name__, smooth))
            return real(*args, **kwargs)

        return called

    for name in ("learning_curves", "overview"):
        monkeypatch.setattr(plotting, name, spy(getattr(plotting, name)))
    args = ["plot", str(sweep_dir), "--formats", "png", "--out"]
    assert main([*args, str(tmp_path / "a"), "--tasks", "circle-3"]) == 0
    assert main([*args, str(tmp_path / "b"), "--smooth", "3"]) == 0
    capsys.readouterr()
    assert asked[0] == ("learning_curves", None) and len(asked) > 2  # then every figure's
    assert set(asked[1:]) == {("learning_curves", 3), ("overview", 3)}, asked


def test_runs_of_other_settings_are_curves_of_their_own_not_seeds(sweep_dir, tmp_path):
    """`sili runs` told SAC at hidden 16 and 32 apart; the plot averaged them as two seeds."""
    copy = tmp_path / "sweep"
    shutil.copytree(sweep_dir, copy)
    config = copy / "runs" / "circle-3__sac__s1" / "config.json"
    record = json.loads(config.read_text())
    hidden = record["run"]["agent"]["hidden"]
    record["run"]["agent"]["hidden"] = hidden + 1
    config.write_text(json.dumps(record))
    fig = learning_curves(load_results(copy), "circle-3")
    ax = next(ax for ax in fig.axes if ax.get_gid() == "task_reward")
    sac = sorted(ln.get_label() for ln in ax.get_lines() if ln.get_label().startswith("SAC"))
    assert sac == [
        f"SAC [agent.hidden={hidden}] (1 seed)",
        f"SAC [agent.hidden={hidden + 1}] (1 seed)",
    ]
    assert "over 1-2 seeds" in fig.get_suptitle()  # SAC's curves have one seed each: named
    assert [ln.get_label() for ln in ax.get_lines()].count("SILI b=0.5") == 1  # the others: two


def test_b_sweep_runs_of_other_settings_are_lines_of_their_own_not_seeds(sweep_dir, tmp_path):
    """The b-sweep figure averaged SILI's seed 1, trained at another hidden size at each b, with
    seed 0 as if it were a seed; its settings are told apart across b, b itself left out."""
    copy = tmp_path / "sweep"
    shutil.copytree(sweep_dir, copy)
    for run in ("circle-3__sili-b0.5__s1", "circle-3__sili-b1__s1"):
        config = copy / "runs" / run / "config.json"
        record = json.loads(config.read_text())
        hidden = record["run"]["agent"]["hidden"]
        record["run"]["agent"]["hidden"] = hidden + 1
        config.write_text(json.dumps(record))
    fig = beta_sweep(load_results(copy), "circle-3", window=4)
    ax = next(ax for ax in fig.axes if ax.get_gid() == "task_reward")
    table = pd.read_csv(sweep_dir / "results.csv")
    for seed, label in (
        (0, f"SILI [agent.hidden={hidden}]"),
        (1, f"SILI [agent.hidden={hidden + 1}]"),
    ):
        rows = table[(table.method == "sili") & (table.seed == seed)].sort_values("interaction")
        finals = rows.groupby("config_beta")["task_reward"].apply(lambda s: s.tail(4).mean())
        xy = _line(ax, label).get_xydata()
        np.testing.assert_array_equal(xy[:, 0], [0.5, 1.0])
        np.testing.assert_allclose(xy[:, 1], finals.to_numpy())


def _sac_run(task: str, task_id: str, interactions: int, **columns) -> pd.DataFrame:
    """A results table of one SAC run of ``task`` (seed 0), ``columns`` on every row."""
    rows = [{"task": task, "run": "r", "seed": 0, "interaction": i} for i in range(interactions)]
    return pd.DataFrame(rows).assign(
        method="sac",
        profile="package",
        config_beta=0.0,
        beta_scheduled=False,
        latent="none",
        task_id=task_id,
        strategy_changed=0,
        stability_reward=0.0,
        **columns,
    )


def test_a_curve_of_one_interaction_is_drawn_as_a_point(tmp_path):
    df = _sac_run(
        "circle-3",
        "sili/Circle3-v1",
        1,
        task_reward=-40.0,
        controller="",
        task_args="",
        true_stability=float("nan"),
    )
    fig = learning_curves(df, "circle-3")
    (line,) = [ln for ln in fig.axes[0].get_lines() if ln.get_label() == "SAC"]
    assert line.get_marker() == "o"  # a line of one point draws nothing
    # SAC has no stability term: its panel says so rather than stand empty
    panel = {a.get_gid(): a for a in fig.axes}["stability_reward"]
    assert [t.get_text() for t in panel.texts] == [NO_STABILITY_TERM]
    reward = {a.get_gid(): a for a in fig.axes}["task_reward"]
    assert not panel.get_lines() and NO_STABILITY_TERM not in [t.get_text() for t in reward.texts]


def test_unfinished_runs_are_left_out_unless_asked(sweep_dir, tmp_path, capsys):
    copy = tmp_path / "sweep"
    shutil.copytree(sweep_dir, copy)
    (copy / "runs" / "circle-3__sac__s1" / "summary.json").unlink()
    df = load_results(copy)
    assert "circle-3__sac__s1" not in set(df["run"])
    xy = _line(learning_curves(df, "circle-3", smooth=1).axes[0], "SAC (1 seed)").get_xydata()
    only_s0 = df[df.run == "circle-3__sac__s0"].sort_values("interaction")["task_reward"]
    np.testing.assert_allclose(xy[:, 1], only_s0)
    assert "circle-3__sac__s1" in set(load_results(copy, include_unfinished=True)["run"])
    assert "fewer where" not in learning_curves(df, "circle-3").get_suptitle()
    plot = ["plot", str(copy), "--formats", "png", "--out", str(tmp_path / "f"), "--tasks"]
    capsys.readouterr()
    assert main([*plot, "circle-3"]) == 0  # the command names what it left out
    left = "note: left out 1 unfinished run (circle-3__sac__s1): --include-unfinished draws them"
    assert left in capsys.readouterr().err
    assert main([*plot, "speaker-listener"]) == 0 and "left out" not in capsys.readouterr().err
    assert main([*plot, "circle-3", "--include-unfinished"]) == 0
    assert "left out" not in capsys.readouterr().err
    metrics = copy / "runs" / "circle-3__sac__s1" / "metrics.csv"
    pd.read_csv(metrics).head(3).to_csv(metrics, index=False)  # it stopped at 3
    partial = learning_curves(load_results(copy, include_unfinished=True), "circle-3")
    assert "2 seeds (fewer where a run ended early; 1 run unfinished)" in partial.get_suptitle()
    one = load_results(copy).query("seed == 0")
    assert "mean ± std over 1 seed, smoothed" in learning_curves(one, "circle-3").get_suptitle()
    for summary in (copy / "runs").glob("*/summary.json"):  # none finished: the command says so
        summary.unlink()
    assert main(["plot", str(copy), "--tasks", "circle-3", "--formats", "png"]) == 2
    assert "has no finished runs yet (`sili runs` shows how far they are" in capsys.readouterr().err
    assert main(["claims", str(copy)]) == 2  # its hint is not plot's alone
    assert "has no finished runs yet (`sili runs` shows how far they are" in capsys.readouterr().err
    figures = copy / "figures"
    assert not figures.exists()
    args = ["plot", str(copy), "--tasks", "circle-3", "--formats", "png", "--include-unfinished"]
    assert main(args) == 0 and (figures / "circle-3.png").is_file()


def test_a_b_sweep_figure_an_earlier_plot_left_is_named_when_none_is_drawn(
    sweep_dir, tmp_path, capsys
):
    copy = tmp_path / "sweep"
    shutil.copytree(sweep_dir, copy)
    plot = ["plot", str(copy), "--formats", "png"]
    assert main(plot) == 0 and "earlier" not in capsys.readouterr().err
    earlier = copy / "figures" / "circle-3_beta.png"
    assert earlier.is_file()
    for seed in (0, 1):  # SILI's runs at b = 1 are unfinished now: one b, no b sweep
        (copy / "runs" / f"circle-3__sili-b1__s{seed}" / "summary.json").unlink()
    started = copy / "runs" / "circle-3__sac__s0"  # a run just started: a header, no rows
    (started / "summary.json").unlink()
    metrics = started / "metrics.csv"
    metrics.write_text(metrics.read_text().splitlines()[0] + "\n")
    assert main(plot) == 0
    err = capsys.readouterr().err
    assert f"note: {earlier} is an earlier plot's: this one draws no b sweep for circle-3" in err
    assert "left out 2 unfinished runs (circle-3__sili-b1__s0, circle-3__sili-b1__s1)" in err


def test_a_sweep_whose_figures_folder_cannot_be_written_is_named(sweep_dir, tmp_path, capsys):
    copy = tmp_path / "sweep"
    shutil.copytree(sweep_dir, copy)
    (copy / "figures").write_text("not a folder")  # as a read-only one: it cannot be written
    assert main(["plot", str(copy), "--formats", "png"]) == 2
    err = capsys.readouterr().err
    assert f"--out (its default) {copy / 'figures'}: cannot write there" in err
    assert "Traceback" not in err
    assert main(["plot", str(copy), "--formats", "png", "--out", str(tmp_path / "f")]) == 0


def test_plot_of_a_non_sweep_exits_2(tmp_path, capsys):
    assert main(["plot", str(tmp_path)]) == 2
    assert "holds no runs" in capsys.readouterr().err
    (tmp_path / "run").mkdir()
    (tmp_path / "run" / "config.json").write_text("{}")
    for command in (["plot"], ["runs"], ["collect", "--into", str(tmp_path / "c")]):
        assert main([*command[:1], str(tmp_path / "nothing"), *command[1:]]) == 2
        assert f"{tmp_path / 'nothing'} does not exist; give a directory written by" in (
            capsys.readouterr().err
        )
        assert main([*command[:1], str(tmp_path / "run"), *command[1:]]) == 2
        assert f"{tmp_path / 'run'} is a run, not a sweep or a collection" in (
            capsys.readouterr().err
        )
        config = tmp_path / "run" / "config.json"  # was "holds no runs (no runs/*/config.json)"
        assert main([*command[:1], str(config), *command[1:]]) == 2
        assert f"{config} is a file, not a folder; give a directory written by" in (
            capsys.readouterr().err
        )
    assert main(["plot", str(tmp_path), "--formats", "gif,png,jpg"]) == 2
    assert "unknown figure format 'gif', 'jpg'; allowed: png, pdf, svg" in capsys.readouterr().err


def test_the_stability_bands_stay_within_their_ranges():
    # three seeds at stability 1, 1, 0: mean 0.67 +- 0.47 would reach 1.14; their stability
    # terms 0, 0, -1: mean -0.33 +- 0.47 would reach 0.14
    n, parts = 6, []
    for seed, stable in enumerate((1.0, 1.0, 0.0)):
        parts.append(
            pd.DataFrame(
                {
                    "run": f"circle-3__lili__s{seed}",
                    "task": "circle-3",
                    "task_id": "sili/Circle3-v1",
                    "method": "lili",
                    "profile": "package",
                    "config_beta": 0.0,
                    "beta_scheduled": False,
                    "controller": "",
                    "latent": "discrete",
                    "seed": seed,
                    "interaction": np.arange(n),
                    "task_reward": np.full(n, -50.0),
                    "true_stability": np.full(n, stable),
                    "stability_reward": np.full(n, stable - 1.0),
                }
            )
        )
    fig = learning_curves(pd.concat(parts, ignore_index=True), "circle-3", smooth=1)
    axes = {a.get_gid(): a for a in fig.axes}
    for metric, top in (("true_stability", 1.0), ("stability_reward", 0.0)):
        ax = axes[metric]
        verts = np.concatenate([p.vertices for p in _band(ax, _line(ax, "LILI")).get_paths()])
        assert verts[:, 1].max() == pytest.approx(top)  # clipped
        low = top - 1 / 3 - np.sqrt(2) / 3  # mean - std
        assert verts[:, 1].min() == pytest.approx(low, abs=1e-9)


def _sili_in_profiles(layout) -> pd.DataFrame:
    """Results-table rows of SILI in the given profiles per task (one seed, 6 interactions)."""
    n, parts = 6, []
    for task, task_id, profiles in layout:
        for profile in profiles:
            parts.append(
                pd.DataFrame(
                    {
                        "run": f"{task}__sili-{profile}__s0",
                        "task": task,
                        "task_id": task_id,
                        "method": "sili",
                        "profile": profile,
                        "config_beta": 0.5,
                        "beta_scheduled": profile == "package",
                        "controller": "",
                        "latent": "discrete",
                        "seed": 0,
                        "interaction": np.arange(n),
                        "task_reward": np.full(n, -20.0),
                        "true_stability": np.full(n, 1.0),
                        "stability_reward": np.zeros(n),
                    }
                )
            )
    return pd.concat(parts, ignore_index=True)


def test_the_overview_names_and_colours_a_profile_alike_in_every_row():
    # SILI ran in both profiles on Circle 3 and in the package's alone on Circle 8
    fig = overview(
        _sili_in_profiles(
            (
                ("circle-3", "sili/Circle3-v1", ("package", "paper")),
                ("circle-8", "sili/Circle8-v1", ("package",)),
            )
        ),
        smooth=1,
    )
    rows = [ax for ax in fig.axes if ax.get_gid() == "task_reward"]
    labels = [[line.get_label() for line in ax.get_lines()] for ax in rows]
    assert [lab for lab in labels[0] if lab.startswith("SILI")] == [
        "SILI (package)",
        "SILI (paper)",
    ]
    assert [lab for lab in labels[1] if lab.startswith("SILI")] == ["SILI (package)"]
    colours = [_line(ax, "SILI (package)").get_color() for ax in rows]
    assert colours[0] == colours[1] != _line(rows[0], "SILI (paper)").get_color()


def test_two_profiles_each_alone_on_its_task_get_two_colours():
    fig = overview(
        _sili_in_profiles(
            (
                ("circle-3", "sili/Circle3-v1", ("package",)),
                ("circle-8", "sili/Circle8-v1", ("paper",)),
            )
        ),
        smooth=1,
    )
    rows = [ax for ax in fig.axes if ax.get_gid() == "task_reward"]
    package, paper = _line(rows[0], "SILI (package)"), _line(rows[1], "SILI (paper)")
    assert to_rgb(package.get_color()) != to_rgb(paper.get_color())  # one legend, told apart


def test_silis_package_runs_are_the_methods_blue_in_every_figure_and_bounds_sit_under_them():
    """SILI was a pale shade of blue where it ran in two profiles and its blue elsewhere; the
    bounds' labels covered the curves near them."""

    both = _sili_in_profiles((("circle-3", "sili/Circle3-v1", ("package", "paper")),))
    alone = _sili_in_profiles((("circle-3", "sili/Circle3-v1", ("package",)),))
    for df, label in ((both, "SILI (package)"), (alone, "SILI")):
        fig = learning_curves(df, "circle-3", smooth=1)
        ax = next(a for a in fig.axes if a.get_gid() == "task_reward")
        line = _line(ax, label)
        assert to_rgb(line.get_color()) == to_rgb(METHOD_COLORS["sili"])
        labels = [t for t in ax.texts if t.get_gid() == "bound_label"]
        assert labels and all(t.get_zorder() < line.get_zorder() for t in labels)


def test_the_overview_has_the_papers_rows_and_says_how_it_smooths():
    df = _sili_in_profiles(
        (
            ("speaker-listener", "sili/SpeakerListener-v1", ("package",)),
            ("driving", "sili/Driving-v0", ("package",)),
            ("circle-3", "sili/Circle3-v1", ("package",)),
        )
    )
    fig = overview(df, smooth=4)
    titles = [ax.get_title(loc="left") for ax in fig.axes if ax.get_gid() == "task_reward"]
    assert titles == ["Circle (3 Goals)", "Driving", "Detour Speaker-Listener"]
    right = [ax.get_title(loc="right") for ax in fig.axes if ax.get_gid() == "true_stability"]
    assert all(t.endswith("smoothed over 4 interactions") for t in right)


def test_curves_are_smoothed_over_about_two_percent_of_the_run_by_default(sweep_dir):
    assert [default_smoothing(n) for n in (10, 100, 1000, 2500)] == [1, 2, 20, 50]
    fig = learning_curves(load_results(sweep_dir), "circle-3")  # 8 interactions
    assert "smoothed over 1 interaction\n" in fig.get_suptitle() + "\n"


def test_a_method_run_in_one_profile_other_than_the_packages_is_labelled_with_it():
    from sili_robots.plot_data import variant_labels

    rows = pd.DataFrame(
        {
            "method": ["sili", "sac"],
            "profile": ["paper", "package"],
            "config_beta": [0.5, 0.5],
            "beta_scheduled": [False, False],
            "controller": ["", ""],
            "task_args": ["", ""],
            "latent": ["discrete", "none"],
            "task_id": ["sili/Circle3-v1"] * 2,
        }
    )
    assert list(variant_labels(rows)) == ["SILI (paper)", "SAC"]


def test_bound_labels_within_the_gap_of_the_one_before_share_a_cluster():
    from sili_robots.plot_bounds import _clusters

    points = [(0.0, "a"), (0.06, "b"), (0.12, "c")]
    assert _clusters(points, 0.07) == [points]
    assert _clusters(points, 0.05) == [[p] for p in points]


def test_bounds_stay_in_view_on_an_empty_panel_and_a_labels_note_is_said_once():
    """A panel with no finite data (runs of one interaction have no stability) kept its empty
    data limits, so its bounds were drawn out of view; the note followed every bound's name."""
    from matplotlib.figure import Figure

    from sili_robots.bounds import stored_bounds
    from sili_robots.plot_bounds import draw_bounds

    ax = Figure().subplots()
    draw_bounds(ax, "true_stability", ["sili/Circle3-v1"], " [default task args]")
    lo, hi = ax.get_ylim()
    values = [v["stability"] for v in stored_bounds("sili/Circle3-v1").values()]
    assert lo <= min(values) and max(values) <= hi
    labels = [t.get_text() for t in ax.texts if t.get_gid() == "bound_label"]
    assert labels and all(t.count("[default task args]") == 1 for t in labels)
    assert all(t.endswith(" [default task args]") for t in labels)


def test_every_overview_panel_names_its_axis_and_a_rows_panels_share_it(sweep_dir):
    fig = overview(load_results(sweep_dir), smooth=2)
    grid = [ax for ax in fig.axes if ax.get_gid()]
    assert all(ax.get_xlabel() == "interaction" for ax in grid)
    for reward, stability in zip(grid[::2], grid[1::2], strict=True):
        assert reward.get_xlim() == stability.get_xlim()  # stability has no interaction 0


def test_formats_that_name_none_are_bad_input(tmp_path, monkeypatch, capsys):
    """--formats "," would draw nothing: refused, not a success without a figure."""
    from sili_robots import plotting

    drawn = []
    monkeypatch.setattr(plotting, "plot_results", lambda *a, **k: drawn.append(k) or [])
    for given in (",", " "):
        assert main(["plot", str(tmp_path), "--formats", given]) == 2
        assert f"unknown figure format {given!r}; allowed" in capsys.readouterr().err
    assert drawn == []


def test_a_scheduled_run_of_the_sweeps_length_is_not_in_the_b_sweep():
    """Without it, a run on a b schedule was drawn in the b sweep at the b it ends at."""

    def run(name, beta, scheduled=False, n=20):
        return pd.DataFrame(
            {
                "run": name,
                "task": "circle-3",
                "method": "sili",
                "profile": "package",
                "config_beta": beta,
                "beta_scheduled": scheduled,
                "interaction": range(n),
            }
        )

    df = pd.concat(
        [run("b0", 0.0), run("b0.5", 0.5), run("b1", 1.0), run("sched", 0.5, scheduled=True)],
        ignore_index=True,
    )
    assert sorted(b_sweep_rows(df, "circle-3")["run"].unique()) == ["b0", "b0.5", "b1"]


def test_bound_labels_stay_inside_their_panel():
    """A bound near the top of a panel has its label below its line, inside the panel, not over
    the title."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    from sili_robots.plot_bounds import draw_bounds

    fig = Figure(figsize=(4, 3))
    FigureCanvasAgg(fig)
    ax = fig.subplots()
    ax.plot([0, 10], [0.0, 0.2])
    draw_bounds(ax, "true_stability", ["sili/Circle3-v1"])
    fig.canvas.draw()
    renderer = fig.canvas.get_renderer()
    box = ax.get_window_extent(renderer)
    labels = [t for t in ax.texts if t.get_gid() == "bound_label"]
    assert len(labels) >= 2
    for t in labels:
        ext = t.get_window_extent(renderer)
        assert box.y0 - 0.5 <= ext.y0 and ext.y1 <= box.y1 + 0.5, (t.get_text(), ext, box)


def test_runs_all_given_one_controller_say_it_in_the_title_and_why_no_bounds_are_drawn():
    """A sweep of one controller (osc) read as the default's: its curves are labelled by what
    sets them apart, which was nothing, and the bounds (measured with mink) were left out
    without a word."""
    df = _sac_run(
        "sawyer-reach",
        "sili/SawyerReach-v1",
        3,
        task_reward=-3.0,
        controller="osc",
        task_args='{"controller": "osc"}',
        true_stability=1.0,
    )
    title = learning_curves(df, "sawyer-reach").get_suptitle()
    assert title.startswith("Sawyer-Reach (controller=osc): mean ± std over 1 seed")
    assert title.endswith("\nno bounds: they were measured with the task's default arguments")
    row = overview(df).axes[0]
    assert row.get_title(loc="left") == "Sawyer-Reach (controller=osc)"
    default = df.assign(controller="", task_args="")
    title = learning_curves(default, "sawyer-reach").get_suptitle()
    assert "(controller" not in title
    assert "\nbounds: scripted policies on sili/SawyerReach-v1" in title
