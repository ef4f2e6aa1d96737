"""The paper's figures from a sweep's results table.

- Per task (``TASK.png/pdf``): task reward, true stability (1 - strategy_changed) and the agent's
  stability reward per interaction, one curve per method (or method variant: b, controller,
  latent kind when a task has several), mean across seeds with a +-1 std band, each run smoothed
  by a trailing moving average before averaging.
- b sweep (``TASK_beta.png/pdf``, tasks where SILI ran with two or more b): final task reward and
  final true stability (mean over each run's last ``window`` interactions) against b, mean and
  std across seeds; one line per controller, task arguments, latent kind and other settings.
- ``overview.png/pdf``: every task's task reward and true stability, one row per task (the
  layout of the paper's results figure).

Every task-reward and true-stability panel also shows the task's reference bounds (``sili
bounds``: the scripted random, still, oracle, stabilizing, ... policies) as labelled horizontal
lines, read from the packaged bounds file for the task version the runs built (the results'
``task_id``; runs recorded before task versions built the first version, and get its bounds).
The bounds were measured with each version's default arguments, so runs given others (another
controller, a margin) get none, and curves that differ only in them are drawn apart.

Figures are built on ``matplotlib.figure.Figure`` (no pyplot state, no display needed); each
curve is a ``Line2D`` labelled with its variant, and each bound a ``LineCollection`` labelled
``bound: KIND`` (gid ``bound``), so what is drawn can be read back and checked. The rows they
draw come from ``plot_data``, the bounds from ``plot_bounds``.
"""

from __future__ import annotations

from collections.abc import Collection, Hashable, Sequence
from pathlib import Path

import numpy as np
import pandas as pd
from matplotlib.axes import Axes
from matplotlib.colors import to_rgb
from matplotlib.figure import Figure

from sili_robots.atomic import replacing
from sili_robots.errors import ConfigError
from sili_robots.labels import METHOD_NAMES, VARIANT_KEYS, file_stem
from sili_robots.plot_bounds import bound_ids, bounds_left_out, draw_bounds
from sili_robots.plot_data import (
    FINAL_METRICS,
    arguments_label,
    b_sweep_rows,
    curve,
    curve_rows,
    default_smoothing,
    final_values,
    shared_arguments,
    variant_labels,
    with_profile,
)
from sili_robots.sweep.state import FIGURES

TASK_TITLES = {
    "circle-3": "Circle (3 Goals)",
    "circle-8": "Circle (8 Goals)",
    "circle-unequal": "Circle (Unequal)",
    "circle-continuous": "Circle (Continuous)",
    "speaker-listener": "Detour Speaker-Listener",
    "driving": "Driving",
    "sawyer-reach": "Sawyer-Reach",
}
METHOD_ORDER = ("sili", "oracle", "lili", "stable", "sac", "smirl")
#: Okabe and Ito's colour-blind-safe palette (tab10's green/red and blue/purple pairs, which
#: overlap in most panels, are near one colour under deuteranopia)
METHOD_COLORS = {
    "sili": "#0072B2",  # blue
    "oracle": "black",
    "lili": "#E69F00",  # orange
    "stable": "#009E73",  # bluish green
    "sac": "#D55E00",  # vermillion
    "smirl": "#CC79A7",  # reddish purple
}
#: what makes one curve: the variant, and the settings its runs have apart from the
#: variant's other runs (``plot_data.load_results``: runs of other ``--set`` are no seeds)
CURVE_KEYS = (*VARIANT_KEYS, "settings")
#: where a curve (``CURVE_KEYS``) says its latent kind
LATENT_KEY = CURVE_KEYS.index("latent")
#: (table column, axis label) of the per-interaction panels
CURVE_METRICS = (
    ("task_reward", "task reward"),
    ("true_stability", "true stability\n(1 − P[strategy changed])"),
    ("stability_reward", "stability term, before b\n(−latent change, or −flagged steps)"),
)

#: what an empty stability-term panel says: it is no curve at 0, there is none to draw
NO_STABILITY_TERM = "no method here learns a latent strategy:\nno stability term to draw"

#: metrics with a range: their seed band is clipped to it (a mean +- std of a fraction can
#: leave it, which would draw a stability above 1, or a stability term, -d <= 0, above 0)
METRIC_RANGES = {"true_stability": (0.0, 1.0), "stability_reward": (-np.inf, 0.0)}


def spread(metric: str, mean: np.ndarray, std: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """mean -+ std, clipped to the metric's range (``METRIC_RANGES``)."""
    low, high = METRIC_RANGES.get(metric, (-np.inf, np.inf))
    return np.clip(mean - std, low, high), np.clip(mean + std, low, high)


def task_title(task: str) -> str:
    """The paper's name of a task; an earlier version gets its version appended."""
    if task in TASK_TITLES:
        return TASK_TITLES[task]
    from sili_robots.tasks.registry import EARLIER_VERSIONS

    spec = EARLIER_VERSIONS.get(task)
    if spec is not None and spec.family in TASK_TITLES:
        return f"{TASK_TITLES[spec.family]} (v{spec.version})"
    return task


def _variant_order(df: pd.DataFrame) -> list[tuple]:
    keys = df[list(CURVE_KEYS)].fillna("").drop_duplicates()
    rank = {m: i for i, m in enumerate(METHOD_ORDER)}
    return sorted(
        (tuple(r) for r in keys.itertuples(index=False)),
        key=lambda k: (rank.get(k[0], len(rank)), k[0], *k[1:]),
    )


def _shades(keys: list[tuple[str, Hashable]]) -> dict[Hashable, object]:
    """Colours for (method, key) pairs: a method's first key gets the method's colour (in
    every figure), the others ever lighter tints of it (never near Oracle's black), never the
    same colour twice."""
    out: dict[Hashable, object] = {}
    for method in dict.fromkeys(m for m, _ in keys):
        mine = list(dict.fromkeys(k for m, k in keys if m == method))
        base = np.array(to_rgb(METHOD_COLORS.get(method, "tab:gray")))
        for key, f in zip(mine, np.linspace(0.0, 0.6, max(len(mine), 2)), strict=False):
            out[key] = tuple(base + (1.0 - base) * f)
    return out


def _colors(variants: list[tuple]) -> dict[Hashable, object]:
    return _shades([(v[0], v) for v in variants])


def _labelled_variants(
    task_rows: pd.DataFrame, profiled: Collection[str] | None
) -> list[tuple[tuple, str, pd.DataFrame]]:
    """(variant, its label, its rows) of one task, in the figures' method order."""
    labels = variant_labels(task_rows, profiled)
    keyed = task_rows[list(CURVE_KEYS)].fillna("").apply(tuple, axis=1)
    out = []
    for variant in _variant_order(task_rows):
        rows = task_rows[keyed == variant]
        out.append((variant, labels[rows.index[0]], rows))
    return out


def _label_palette(
    rows_per_task: Sequence[pd.DataFrame], profiled: Collection[str]
) -> dict[Hashable, object]:
    """One colour per label across a multi-task figure, so that two labels of one method (two
    profiles, each alone on its task) are told apart in the one legend."""
    return _shades(
        [
            (variant[0], label)
            for task_rows in rows_per_task
            for variant, label, _ in _labelled_variants(task_rows, profiled)
        ]
    )


def _draw_curves(
    axes: Sequence[Axes],
    task_rows: pd.DataFrame,
    metrics: Sequence[tuple[str, str]],
    window: int,
    profiled: Collection[str] | None = None,
    palette: dict[Hashable, object] | None = None,
    name_fewer_seeds: bool = False,
) -> None:
    """``profiled`` and ``palette`` (label -> colour, ``_label_palette``) keep one label and one
    colour per variant across the rows of a multi-task figure; ``name_fewer_seeds`` labels a
    curve averaging fewer seeds than the most with its count (a title says only "1-3 seeds")."""
    colors = _colors(_variant_order(task_rows))
    palette = {} if palette is None else palette
    most = task_rows.groupby(list(CURVE_KEYS), dropna=False)["seed"].nunique().max()
    for variant, label, rows in _labelled_variants(task_rows, profiled):
        color = palette.setdefault(label, colors[variant])
        seeds = rows["seed"].nunique()
        if name_fewer_seeds and seeds < most:
            label = f"{label} ({seeds} seed{'s' if seeds > 1 else ''})"
        style = "--" if variant[0] == "oracle" else "-"
        for ax, (metric, _) in zip(axes, metrics, strict=True):
            if metric == "stability_reward" and variant[LATENT_KEY] == "none":
                continue  # no latent, so no change of it to pay for: not a perfect 0
            stats = curve(rows, metric, window)
            x = stats.index.to_numpy(float)
            mean, std = stats["mean"].to_numpy(), stats["std"].to_numpy()
            marker = "o" if len(x) == 1 else None  # a run of one interaction: a point, not a line
            ax.plot(x, mean, style, color=color, label=label, lw=1.6, marker=marker)
            ax.fill_between(x, *spread(metric, mean, std), color=color, alpha=0.18, lw=0)
    task_ids = bound_ids(task_rows, str(task_rows["task"].iloc[0]))
    mixed = (task_rows["task_args"] != "").any()  # the bounds hold for some curves only
    for ax, (metric, ylabel) in zip(axes, metrics, strict=True):
        if metric == "stability_reward" and (task_rows["latent"] == "none").all():
            ax.text(0.5, 0.5, NO_STABILITY_TERM, transform=ax.transAxes, ha="center", color="0.4")
        draw_bounds(ax, metric, task_ids, " [default task args]" if mixed else "")
        ax.set_ylabel(ylabel)
        ax.set_xlabel("interaction")
        ax.set_gid(metric)
        ax.grid(alpha=0.3)


def _seed_note(rows: pd.DataFrame) -> str:
    """How many seeds each curve averages; unfinished runs of a variant average fewer late."""
    keys = list(CURVE_KEYS)
    seeds = rows.groupby(keys, dropna=False)["seed"].nunique()
    lo, hi = int(seeds.min()), int(seeds.max())
    note = f"{lo} seed{'s' if lo > 1 else ''}" if lo == hi else f"{lo}-{hi} seeds"
    ends = rows.groupby([*keys, "run"], dropna=False)["interaction"].max()
    asides = []
    if (ends.groupby(level=keys, dropna=False).nunique() > 1).any():
        asides.append("fewer where a run ended early")
    if "finished" in rows:  # --include-unfinished: a curve may stop short of its run's end
        unfinished = rows.loc[~rows["finished"].astype(bool), "run"].nunique()
        if unfinished:
            asides.append(f"{unfinished} run{'s' if unfinished > 1 else ''} unfinished")
    return note + (f" ({'; '.join(asides)})" if asides else "")


def learning_curves(df: pd.DataFrame, task: str, smooth: int | None = None) -> Figure:
    """Task reward, true stability and stability reward per interaction for every method."""
    df = with_profile(df)
    rows = curve_rows(df, task)
    if rows.empty:
        raise ConfigError(
            f"no results for task {task!r}; tasks in the table: {sorted(set(df.task))}"
        )
    window = smooth or default_smoothing(int(rows["interaction"].max()) + 1)
    fig = Figure(figsize=(14, 4.0), layout="constrained")
    axes = fig.subplots(1, len(CURVE_METRICS), sharex=True)
    _draw_curves(axes, rows, CURVE_METRICS, window, name_fewer_seeds=True)
    ids = ", ".join(bound_ids(rows, task))
    if ids and (rows["task_args"] != "").any():
        ids += " (its default task arguments)"
    shared = shared_arguments(rows)
    bounds = f"\nbounds: scripted policies on {ids}" if ids else ""
    if bounds_left_out(rows, task):
        bounds = "\nno bounds: they were measured with the task's default arguments"
    fig.suptitle(
        f"{task_title(task)}{shared}: mean ± std over {_seed_note(rows)}, "
        f"smoothed over {window} interaction{'s' if window > 1 else ''}{bounds}"
    )
    fig.legend(*axes[0].get_legend_handles_labels(), loc="outside right upper")
    return fig


def beta_sweep(df: pd.DataFrame, task: str, window: int = 100, method: str = "sili") -> Figure:
    """Final task reward and final true stability against b (mean and std across seeds)."""
    rows = b_sweep_rows(with_profile(df), task, method)
    if rows["config_beta"].nunique() < 2:
        raise ConfigError(
            f"task {task!r} has no b sweep of {method} (needs runs with two or more b values)"
        )
    finals = final_values(rows, window)
    fig = Figure(figsize=(10, 4.0), layout="constrained")
    axes = fig.subplots(1, len(FINAL_METRICS))
    keys = ["controller", "task_args", "latent", "b_settings"]
    groups = [tuple(g) for g in finals[keys].fillna("").drop_duplicates().values]
    shades = _shades([(method, g) for g in groups])  # the method's colour, then its tints
    for group in groups:
        controller, task_args, latent, settings = group
        part = finals[(finals[keys].fillna("") == group).all(axis=1)]
        color = shades[group]
        label = METHOD_NAMES.get(method, method)  # plus what sets the lines apart
        if len({g[0] for g in groups}) > 1:
            label += f" [{controller or 'default'}]"
        label += arguments_label(task_args) if len({g[1] for g in groups}) > 1 else ""
        label += f" ({latent})" if len({g[2] for g in groups}) > 1 else ""
        label += f" [{settings}]" if len({g[3] for g in groups}) > 1 and settings else ""
        for ax, (metric, ylabel) in zip(axes, FINAL_METRICS, strict=True):
            stats = part.groupby("config_beta")[metric].agg(["mean", lambda s: s.std(ddof=0)])
            stats.columns = ["mean", "std"]
            b = stats.index.to_numpy(float)
            mean = stats["mean"].to_numpy()
            ax.plot(b, mean, "o-", label=label, lw=1.6, color=color)
            low, high = spread(metric, mean, stats["std"].to_numpy())
            yerr = np.stack([mean - low, high - mean])
            ax.errorbar(b, mean, yerr=yerr, fmt="none", color=color, capsize=4)
            ax.set_xlabel("stability weight b")
            ax.set_ylabel(ylabel)
            ax.set_gid(metric)
            ax.grid(alpha=0.3)
    seeds = finals.groupby("config_beta")["seed"].nunique()
    seed_text = f"{seeds.min()}" if seeds.min() == seeds.max() else f"{seeds.min()}-{seeds.max()}"
    length = int(rows.groupby("run").size().min())  # b_sweep_rows: runs of one length
    last = min(window, length)
    fig.suptitle(
        f"{task_title(task)}: effect of b on {METHOD_NAMES.get(method, method)} after {length:,} "
        f"interactions (mean of the last {last}; mean ± std over {seed_text} "
        f"seed{'s' if seeds.max() > 1 else ''})"
    )
    if len(groups) > 1:
        fig.legend(*axes[0].get_legend_handles_labels(), loc="outside right upper")
    return fig


#: the rows of the paper's results figure, top to bottom
PAPER_ROWS = (
    "circle-3",
    "circle-8",
    "circle-unequal",
    "driving",
    "sawyer-reach",
    "circle-continuous",
    "speaker-listener",
)


def overview(df: pd.DataFrame, smooth: int | None = None) -> Figure:
    """One row per task: task reward and true stability per interaction, in the rows of the
    paper's results figure (its right column is the stability reward)."""
    df = with_profile(df)
    tasks = [t for t in PAPER_ROWS if t in set(df["task"])] + sorted(
        set(df["task"]) - set(PAPER_ROWS)
    )
    metrics = CURVE_METRICS[:2]
    fig = Figure(figsize=(11, 2.7 * len(tasks) + 0.6), layout="constrained")
    grid = np.atleast_2d(fig.subplots(len(tasks), len(metrics), squeeze=False, sharex="row"))
    handles: dict[str, object] = {}
    shown = {task: curve_rows(df, task) for task in tasks}
    # a method that ran in two profiles anywhere names its profile in every row, one colour each
    both = pd.concat(shown.values()).groupby("method")["profile"].nunique() > 1
    profiled = set(both[both].index)
    palette = _label_palette(list(shown.values()), profiled)
    for row, task in zip(grid, tasks, strict=True):
        rows = shown[task]
        window = smooth or default_smoothing(int(rows["interaction"].max()) + 1)
        _draw_curves(row, rows, metrics, window, profiled, palette)
        row[0].set_title(task_title(task) + shared_arguments(rows), loc="left", fontsize=10)
        row[-1].set_title(
            f"mean ± std over {_seed_note(rows)}, smoothed over {window} "
            f"interaction{'s' if window > 1 else ''}",
            loc="right",
            fontsize=8,
        )
        for h, lab in zip(*row[0].get_legend_handles_labels(), strict=True):
            handles.setdefault(lab, h)
    fig.legend(list(handles.values()), list(handles), loc="outside right upper")
    return fig


def save_figure(fig: Figure, stem: Path, formats: Sequence[str] = ("png", "pdf")) -> list[Path]:
    """``fig`` as ``stem.png``, ``stem.pdf``, ... (the stem kept whole, dots and all), each
    replaced whole: a failed write keeps the figure drawn before."""
    stem.parent.mkdir(parents=True, exist_ok=True)
    paths = []
    for fmt in formats:
        path = stem.parent / f"{stem.name}.{fmt}"
        with replacing(path) as tmp:
            fig.savefig(tmp, dpi=150, format=fmt)
        paths.append(path)
    return paths


def plot_results(
    df: pd.DataFrame,
    sweep_dir: Path,
    out_dir: Path | None = None,
    smooth: int | None = None,
    window: int = 100,
    formats: Sequence[str] = ("png", "pdf"),
    tasks: Sequence[str] | None = None,
) -> list[Path]:
    """Write every figure of a sweep's table ``df`` (``load_results`` of ``sweep_dir``), or
    only those of ``tasks`` (no overview then); returns the files written."""
    out_dir = Path(out_dir) if out_dir is not None else Path(sweep_dir) / FIGURES
    written: list[Path] = []
    present = [t for t in TASK_TITLES if t in set(df["task"])] + sorted(
        set(df["task"]) - set(TASK_TITLES)
    )
    missing = [t for t in tasks or () if t not in present]
    if missing:
        raise ConfigError(
            f"task {missing[0]!r} has no runs in {sweep_dir}; its tasks: {', '.join(present)}"
        )
    for task in tasks or present:
        stem = out_dir / file_stem(task)
        written += save_figure(learning_curves(df, task, smooth), stem, formats)
        if b_sweep_rows(df, task)["config_beta"].nunique() > 1:
            written += save_figure(
                beta_sweep(df, task, window), stem.with_name(f"{stem.name}_beta"), formats
            )
    if not tasks:
        written += save_figure(overview(df, smooth), out_dir / "overview", formats)
    return written
