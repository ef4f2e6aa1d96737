"""The reference bounds on a figure's panels: the packaged bounds (``sili bounds``) of the task
versions the runs built, as labelled horizontal lines, labels of lines close together merged."""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np
import pandas as pd

from sili_robots.errors import ConfigError

if TYPE_CHECKING:
    from matplotlib.axes import Axes

#: the panels that show reference bounds, and the bound each one reads
BOUND_METRICS = {"task_reward": "task_reward", "true_stability": "stability"}
#: (colour, dash pattern) of each bound kind's line
BOUND_STYLES = {
    "random": ("0.6", (0, (1, 2))),
    "still": ("tab:olive", (0, (1, 2))),
    "oracle": ("0.4", (0, (6, 2, 1, 2))),  # apart from the Oracle method's black
    "stabilizing": ("tab:cyan", (0, (6, 2, 1, 2))),
    "blind": ("tab:pink", (0, (3, 2))),
    "tracking": ("tab:brown", (0, (3, 2))),
}


def _task_ids(rows: pd.DataFrame, task: str) -> list[str]:
    """The task versions the rows' runs built (the current one when the table has no column)."""
    if "task_id" in rows and rows["task_id"].notna().any():
        return sorted(str(t) for t in rows["task_id"].dropna().unique())
    from sili_robots.tasks import task_spec

    try:
        return [task_spec(task).gym_id]
    except ConfigError:
        return []


def bound_ids(rows: pd.DataFrame, task: str) -> list[str]:
    """The task versions whose stored bounds hold for ``rows``: those of the runs built with
    their version's default arguments (bounds were measured with them; none for the others)."""
    default = rows[rows["task_args"] == ""]
    return _task_ids(default, task) if len(default) else []


def bounds_left_out(rows: pd.DataFrame, task: str) -> bool:
    """Whether the runs' task versions have stored bounds that no run can be shown with: every
    run was given other task arguments than those the bounds were measured with."""
    from sili_robots.bounds import stored_bounds

    return not bound_ids(rows, task) and any(stored_bounds(t) for t in _task_ids(rows, task))


def draw_bounds(ax: Axes, metric: str, task_ids: Sequence[str], note: str = "") -> None:
    """The stored bounds of ``task_ids`` as labelled horizontal lines across ``ax`` (a panel of
    ``BOUND_METRICS``), all kept in view; bounds close together share one label at the right
    edge, each kind with its value, and the label ends with ``note`` (e.g. that they hold for the
    default task arguments only, on a panel that also has runs given others)."""
    from matplotlib.collections import LineCollection
    from matplotlib.transforms import blended_transform_factory

    from sili_robots.bounds import stored_bounds

    key = BOUND_METRICS.get(metric)
    if key is None:
        return
    trans = blended_transform_factory(ax.transAxes, ax.transData)
    drawn: list[tuple[float, str]] = []
    for task_id in task_ids:
        suffix = f" ({task_id.rsplit('-', 1)[-1]})" if len(task_ids) > 1 else ""
        for kind, values in stored_bounds(task_id).items():
            y = float(values[key])
            color, dashes = BOUND_STYLES.get(kind, ("0.5", (0, (2, 2))))
            lines = LineCollection(
                [[(0.0, y), (1.0, y)]],
                colors=[color],
                linestyles=[dashes],
                linewidths=1.1,
                transform=trans,
                label=f"bound: {kind}{suffix}",
                zorder=1.5,
            )
            lines.set_gid("bound")
            ax.add_collection(lines, autolim=False)
            # y alone counts: any finite x (an empty panel's dataLim.x0 is inf, a dropped point)
            ax.update_datalim([(0.0, y)], updatex=False)
            drawn.append((y, f"{kind}{suffix}"))
    if not drawn:
        return
    ax.autoscale_view()
    lo, hi = ax.get_ylim()
    for cluster in _clusters(sorted(drawn), 0.07 * (hi - lo)):
        ys = [y for y, _ in cluster]
        at = float(np.mean(ys))
        by_value: dict[str, list[str]] = {}
        for y, kind in cluster:
            by_value.setdefault(f"{y:.2f}", []).append(kind)
        text = "; ".join(f"{', '.join(kinds)} {v}" for v, kinds in by_value.items()) + note
        upper = (at - lo) > 0.5 * (hi - lo)
        ax.annotate(
            text,
            xy=(0.995, at),
            xycoords=trans,
            xytext=(0, -3 if upper else 3),
            textcoords="offset points",
            ha="right",
            va="top" if upper else "bottom",
            fontsize=6.5,
            color="0.25",
            bbox={"boxstyle": "square,pad=0.1", "fc": "white", "ec": "none", "alpha": 0.5},
            gid="bound_label",
            zorder=1.6,  # over the bound lines and the runs' spreads, under their curves
        )


def _clusters(points: list[tuple[float, str]], gap: float) -> list[list[tuple[float, str]]]:
    """Sorted ``(y, name)`` points grouped where consecutive ys are within ``gap``."""
    out: list[list[tuple[float, str]]] = []
    for point in points:
        if out and point[0] - out[-1][-1][0] <= gap:
            out[-1].append(point)
        else:
            out.append([point])
    return out
