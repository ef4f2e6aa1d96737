"""Run a sweep: plan its runs, skip finished ones, hand the rest to a backend, write the tables."""

from __future__ import annotations

import contextlib
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path

from sili_robots.errors import ConfigError, check_flag
from sili_robots.runs import (
    CONFIG,
    STOP_FILE,
    recorded_run,
    same_run,
    with_settings_of,
    write_config,
)
from sili_robots.sweep import tensorboard
from sili_robots.sweep.backend import Backend, Monitor
from sili_robots.sweep.local import LocalBackend
from sili_robots.sweep.spec import PlannedRun, SweepSpec, expand
from sili_robots.sweep.state import (
    RUNNING_FILE,
    RUNS_DIR,
    SWEEP_FILE,
    check_existing,
    check_not_training,
    clear_sweep,
    record_invocation,
    recorded_specs,
    run_path,
    run_state,
    shorter_run,
    sweep_lock,
    training_worker,
    write_invocations,
)
from sili_robots.sweep.worker import Job, Outcome


@dataclass
class SweepReport:
    """What one invocation did: runs skipped as already finished, and each run's outcome."""

    sweep_dir: Path
    planned: list[str]
    skipped: list[str] = field(default_factory=list)
    outcomes: dict[str, Outcome] = field(default_factory=dict)

    @property
    def failed(self) -> dict[str, str]:
        return {n: o.error or "" for n, o in self.outcomes.items() if o.status != "done"}

    @property
    def ok(self) -> bool:
        return not self.failed and len(self.outcomes) + len(self.skipped) == len(self.planned)


def plan(specs: Sequence[SweepSpec]) -> list[PlannedRun]:
    """The union of the specs' runs (a run named twice must be the same run, but for what the
    later one's machine timed, as invocations on two machines may time other kernels for it,
    and how often it is saved, which changes no number it logs; the first wins)."""
    runs: dict[str, PlannedRun] = {}
    for spec in specs:
        for run in expand(spec):
            prev = runs.get(run.name)
            either = {*run.timed, "checkpoint_every"}
            if prev is not None and not same_run(prev.config, run.config, either):
                raise ConfigError(f"run {run.name} is planned twice with different settings")
            runs.setdefault(run.name, run)
    return list(runs.values())


def as_made(sweep_dir: Path, planned: Sequence[PlannedRun]) -> list[PlannedRun]:
    """The planned runs, each one already on disk with the kernels it was made with where this
    machine's timing chose them (``PlannedRun.timed``; a setting given is kept, and checked):
    it goes on with them on any machine, as ``sili train --resume`` does, while a new run takes
    the invocation's (the same sweep re-run elsewhere, e.g. for more seeds, was refused)."""
    out = []
    for run in planned:
        folder = run_path(sweep_dir, as_found(sweep_dir, run).name)
        if (folder / CONFIG).is_file():
            with contextlib.suppress(ConfigError, KeyError, TypeError, AttributeError):
                made = with_settings_of(run.config, recorded_run(folder), run.timed)
                run = replace(run, config=made)
        out.append(run)  # a damaged config stays as planned: check_existing names it
    return out


def former_folder(sweep_dir: Path, run: PlannedRun) -> Path | None:
    """The run's folder under a name an earlier version gave it, when only that one exists."""
    if run_path(sweep_dir, run.name).exists():
        return None
    formers = (run_path(sweep_dir, name) for name in run.former_names)
    return next((folder for folder in formers if folder.is_dir()), None)


def as_found(sweep_dir: Path, run: PlannedRun) -> PlannedRun:
    """The run under the name its folder has on disk (an earlier version's, until renamed)."""
    former = former_folder(sweep_dir, run)
    return run if former is None else replace(run, name=former.name)


def check_planned(
    sweep_dir: Path, planned: Sequence[PlannedRun], recorded: bool
) -> tuple[dict[str, PlannedRun], list[PlannedRun]]:
    """Check every planned run as found on disk before anything changes: its files agree with
    its config, or (``recorded``, a resume) it is shorter, an extension cut short or asked for
    now, which goes on to the planned budget; no live process trains it (e.g. ``sili train
    --resume``); and a record a new invocation joins reads back. Returns the runs as found, by
    name, and the shorter ones."""
    if not recorded and (Path(sweep_dir) / SWEEP_FILE).is_file():
        recorded_specs(sweep_dir)
    found = {run.name: as_found(sweep_dir, run) for run in planned}
    shorter = [run for run in planned if recorded and shorter_run(sweep_dir, found[run.name])]
    for run in planned:
        if run not in shorter:
            check_existing(sweep_dir, found[run.name])
        check_not_training(sweep_dir, found[run.name].name)
    return found, shorter


def adopt_former_names(sweep_dir: Path, planned: Sequence[PlannedRun]) -> None:
    """Rename each planned run's folder that an earlier version named otherwise, so the run
    resumes (or counts as done) under its name instead of being trained again beside it."""
    for run in planned:
        former = former_folder(sweep_dir, run)
        if former is not None:
            former.rename(run_path(sweep_dir, run.name))


def replaced_runs(sweep_dir: Path, planned: Sequence[PlannedRun]) -> list[str]:
    """The runs ``--overwrite`` removes: the planned ones and those the recorded sweep plans.
    ConfigError when that cannot be told safely: the folder is a results collection (its runs may
    be the only copy), the record is damaged, or a run is being trained."""
    sweep_dir = Path(sweep_dir)
    names = _own_names(planned)
    runs_dir = sweep_dir / RUNS_DIR
    if (sweep_dir / SWEEP_FILE).is_file():
        try:
            recorded = plan(recorded_specs(sweep_dir))
        except ConfigError as err:
            raise ConfigError(
                f"{err}; --overwrite cannot tell which runs are the sweep's: remove {sweep_dir} "
                "yourself or give another --out"
            ) from None
        names += [n for n in _own_names(recorded) if n not in names]
    elif runs_dir.is_dir() and any(runs_dir.iterdir()):
        raise ConfigError(
            f"{sweep_dir} is a results collection, not a sweep (no {SWEEP_FILE}): --overwrite "
            "replaces only a sweep; give another --out"
        )
    for name in names:
        check_not_training(sweep_dir, name)
    return names


def _own_names(planned: Sequence[PlannedRun]) -> list[str]:
    """The runs' names, and the names earlier versions gave them (``PlannedRun.former_names``)."""
    return [n for r in planned for n in (r.name, *r.former_names)]


def extended(specs: Sequence[SweepSpec], interactions: int, sweep_dir: Path) -> list[SweepSpec]:
    """The recorded ``specs`` with their budget raised to ``interactions`` (``--resume
    --interactions``); ConfigError when that would shorten one."""
    longest = max(s.interactions for s in specs)
    if interactions < longest:
        raise ConfigError(
            f"--interactions {interactions} would shorten the sweep in {sweep_dir}, whose runs "
            f"are set to up to {longest}; a sweep can only be extended (allowed: >= {longest})"
        )
    return [replace(s, interactions=interactions) for s in specs]


def run_sweep(
    specs: SweepSpec | Sequence[SweepSpec],
    sweep_dir: Path,
    backend: Backend | None = None,
    monitor: Monitor | None = None,
    progress: bool = True,
    tensorboard_scalars: bool | None = None,
    overwrite: bool = False,
    recorded: bool = False,
) -> SweepReport:
    """Run every planned run not yet finished; failures are reported, never raised.

    With ``overwrite`` the sweep in ``sweep_dir`` (its record, tables and runs) is removed
    first, so every run starts anew. ``recorded``: ``specs`` are the sweep's record (``--resume``),
    perhaps with a raised budget; the record is replaced by them, and each run made with a
    smaller budget goes on to the new one as a run started with it would have
    (``sili_robots.training.extend``), also after an extension cut short.

    Without a ``monitor`` a :class:`SweepProgress` prints one line per run that ends and, with
    ``progress``, draws the live display.

    ``tensorboard_scalars`` None means: on when the ``tensorboard`` package is installed.
    """
    from sili_robots.sweep.progress import SweepProgress
    from sili_robots.sweep.results import write_tables

    specs = [specs] if isinstance(specs, SweepSpec) else list(specs)
    if not specs or not all(isinstance(s, SweepSpec) for s in specs):
        raise ConfigError(f"specs must be a SweepSpec or a non-empty list of them, got {specs!r}")
    sweep_dir = Path(sweep_dir)
    planned = plan(specs)
    backend = backend or LocalBackend()
    for name, given, needs in (("backend", backend, "run"), ("monitor", monitor, "finished")):
        if given is not None and not callable(getattr(given, needs, None)):
            raise ConfigError(f"{name} must be a sweep {name} (LocalBackend, ...), got {given!r}")
    progress = check_flag("progress", progress)
    overwrite, recorded = check_flag("overwrite", overwrite), check_flag("recorded", recorded)
    if tensorboard_scalars is not None:
        tensorboard_scalars = check_flag("tensorboard_scalars", tensorboard_scalars)
    if tensorboard_scalars is None:
        tensorboard_scalars = tensorboard.available()
    elif tensorboard_scalars and not tensorboard.available():
        raise ConfigError("TensorBoard scalars need: pip install 'sili-robots[tensorboard]'")
    with sweep_lock(sweep_dir):
        if overwrite:
            clear_sweep(sweep_dir, replaced_runs(sweep_dir, planned))
        planned = as_made(sweep_dir, planned)
        _, shorter = check_planned(sweep_dir, planned, recorded)
        adopt_former_names(sweep_dir, planned)
        if recorded:
            write_invocations(sweep_dir, specs)
        if shorter:
            from sili_robots.training import extend as extend_run  # torch: only when needed

            for run in shorter:
                path = run_path(sweep_dir, run.name)
                extend_run(path, run.config.interactions)  # and unfinished: no summary
        for spec in specs:
            record_invocation(sweep_dir, spec)
        report = SweepReport(sweep_dir, [r.name for r in planned])
        jobs: list[Job] = []
        for run in planned:
            path = run_path(sweep_dir, run.name)
            if training_worker(path) is None:  # stale: its process is gone (a live one since
                (path / RUNNING_FILE).unlink(missing_ok=True)  # check_planned: its worker says)
            (path / STOP_FILE).unlink(missing_ok=True)  # an earlier stopped sweep's
            if run_state(path) == "done":
                report.skipped.append(run.name)
                continue
            if run_state(path) == "new":
                write_config(path, run.config)  # listed in the tables even if it fails early
            jobs.append(Job(run.name, run.config.to_dict(), str(path), tensorboard_scalars))
        display = None
        if monitor is None:
            display = SweepProgress(
                jobs,
                {r.name: r.config.interactions for r in planned},
                already_done=len(report.skipped),
                enabled=progress,
            )
            monitor = display
        try:
            with display or contextlib.nullcontext():
                outcomes = backend.run(jobs, monitor) if jobs else []
        finally:
            write_tables(sweep_dir)
        report.outcomes = {o.name: o for o in outcomes}
    return report
