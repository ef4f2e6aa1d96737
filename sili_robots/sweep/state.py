"""A sweep directory on disk: where runs live, what state each is in, and who owns the sweep.

Layout::

    SWEEP_DIR/sweep.json        every invocation's spec (the sweep can be re-run from it)
    SWEEP_DIR/runs/NAME/        one run directory per run (``sili_robots.runs``)
    SWEEP_DIR/results.csv       tidy table, one row per run per interaction
    SWEEP_DIR/runs.csv          one row per run: status, final numbers, error
    SWEEP_DIR/figures/          ``sili plot``

A run is *done* when it has ``summary.json``, *resumable* when it has ``checkpoint.pt`` but no
summary, *new* otherwise (a run killed before its first checkpoint starts over).
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import os
import socket
from collections.abc import Callable, Iterator
from dataclasses import replace
from pathlib import Path
from typing import Literal

from sili_robots.atomic import write_text
from sili_robots.errors import ConfigError
from sili_robots.labels import file_stem, shell_path
from sili_robots.metrics import COMPRESSED_METRICS
from sili_robots.runs import (
    CHECKPOINT,
    CONFIG,
    ERROR_FILE,
    RUNNING_FILE,
    RUNS_DIR,
    SUMMARY,
    check_resumable,
    clear_run,
    foreign_files,
    listed,
    read_json,
    recorded_run,
    run_differences,
    shown_value,
)
from sili_robots.sweep.spec import PlannedRun, SweepSpec, expand

SWEEP_FILE, RESULTS, RUNS_TABLE, LOCK, FIGURES = (
    "sweep.json",
    "results.csv",
    "runs.csv",
    ".lock",
    "figures",
)
#: the formats ``sili plot`` writes its figures in
FIGURE_FORMATS = ("png", "pdf", "svg")
DAMAGED_SWEEP = "it is not a sweep's record, so the sweep cannot resume"

RunState = Literal["done", "resumable", "new"]


def check_sweep_dir(path: Path, option: str) -> None:
    """``path`` is a sweep or a results collection, or new or empty: a sweep never writes its
    tables and runs among files of something else (a run, a user's own tables)."""
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise ConfigError(f"{option} {path} is a file; give a directory")
    if path.is_dir() and not (path / SWEEP_FILE).exists() and not (path / RUNS_DIR).is_dir():
        others = foreign_files(path)
        if others:
            raise ConfigError(
                f"{option} {path} is not a sweep or a results collection but holds files "
                f"({listed(others)}); give a new or empty directory"
            )


def check_collection_dir(path: Path, option: str) -> None:
    """``check_sweep_dir`` for a results collection to copy runs into; a sweep is refused too:
    its runs would be replaced by their small copies."""
    check_sweep_dir(path, option)
    if (Path(path) / SWEEP_FILE).exists():
        raise ConfigError(
            f"{option} {path} is a sweep; collect into a results collection or a new or empty "
            "directory"
        )


def check_not_in_a_sweep(path: Path, option: str) -> None:
    """A new run is never made in a sweep's or a collection's ``runs/``: the sweep plans its
    own settings under that name (and would not resume it), a collection holds finished runs."""
    runs, holder = Path(path).resolve().parent, Path(path).resolve().parent.parent
    if runs.name != RUNS_DIR or not runs.is_dir():
        return
    if (holder / SWEEP_FILE).is_file():
        raise ConfigError(
            f"{option} {path} is in the sweep {holder}: `sili sweep --resume {holder}` trains "
            "its runs; give a folder outside it"
        )
    others = [p for p in runs.iterdir() if p.name != Path(path).name]
    if any((p / COMPRESSED_METRICS).is_file() for p in others):
        raise ConfigError(
            f"{option} {path} is in the results collection {holder} (`sili collect`), which "
            "holds finished runs; give a folder outside it"
        )


def run_path(sweep_dir: Path, name: str) -> Path:
    return Path(sweep_dir) / RUNS_DIR / name


def _plotted_name(task: str) -> str:
    """The name a run records of ``task`` as the sweep was given it (``sili/Circle3-v1`` is
    ``circle-3``), which names its figures; a user's class path as it is (not imported)."""
    from sili_robots.build import canonical_task, is_class_path

    try:
        return task if is_class_path(task) else canonical_task(task)
    except ConfigError:
        return task


def _plotted_figures(sweep_dir: Path) -> list[Path]:
    """The figures ``sili plot`` wrote into the sweep's folder for its tasks (a user's own
    files beside them, or all of them when the record is damaged, stay)."""
    try:
        tasks = {_plotted_name(t) for spec in recorded_specs(sweep_dir) for t in spec.tasks}
    except ConfigError:
        return []
    stems = {"overview", *map(file_stem, tasks), *(f"{file_stem(t)}_beta" for t in tasks)}
    return [
        path
        for fmt in FIGURE_FORMATS
        for path in (Path(sweep_dir) / FIGURES).glob(f"*.{fmt}")
        if path.name.removesuffix(f".{fmt}") in stems
    ]


def clear_sweep(sweep_dir: Path, names: list[str]) -> None:
    """Remove a sweep's own files (the runs ``names``, its tables, ``sili plot``'s figures) and
    leave anything else a user put there; its record last, so a removal cut short still leaves
    a folder that is a sweep's."""
    sweep_dir = Path(sweep_dir)
    for name in names:
        path = run_path(sweep_dir, name)
        if path.is_dir():
            clear_run(path)
            with contextlib.suppress(OSError):
                path.rmdir()  # kept when a user's file is in it
    for figure in _plotted_figures(sweep_dir):
        figure.unlink()
    with contextlib.suppress(OSError):
        (sweep_dir / FIGURES).rmdir()
    for name in (RESULTS, RUNS_TABLE, SWEEP_FILE):
        (sweep_dir / name).unlink(missing_ok=True)


def training_worker(run_dir: Path) -> int | None:
    """The process id of a live process on this host training ``run_dir`` (a sweep worker or
    ``sili train``), if any: a second process training the same run would interleave its files."""
    try:
        info = json.loads((Path(run_dir) / RUNNING_FILE).read_text())
        pid = int(info["pid"])
    except (OSError, ValueError, KeyError, TypeError):
        return None
    if not 0 < pid < 2**22:  # no process's (Linux's pid_max): a damaged file, nobody trains
        return None
    if info.get("host") != socket.gethostname():
        return None  # another machine's (Ray): nothing to ask from here
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return None
    except PermissionError:
        pass  # alive, another user's
    started = info.get("started")
    if started is not None and process_started(pid) not in (None, started):
        return None  # the pid is another process's now (the claim's outlived a kill -9)
    return pid


def process_started(pid: int) -> str | None:
    """Which process ``pid`` is: this boot's id and its start time (Linux); None elsewhere.
    A pid alone is reused once its process is gone, after a reboot or in a new container."""
    try:
        boot = Path("/proc/sys/kernel/random/boot_id").read_text().strip()
        stat = Path(f"/proc/{pid}/stat").read_text()
        return f"{boot}:{stat.rsplit(')', 1)[1].split()[19]}"  # field 22: start time, in ticks
    except (OSError, IndexError):
        return None


@contextlib.contextmanager
def training_claim(run_dir: Path, before: Callable[[], None] | None = None) -> Iterator[None]:
    """Mark ``run_dir`` as trained by this process while the block runs, so that a sweep or a
    second ``sili train --resume`` refuses it (``training_worker``) instead of training beside;
    ``RunBeingTrained`` when another live process has claimed it. The check and the claim are
    one step (under a lock on the folder): of two trainers started together, one trains.
    ``before`` runs in that step too (a new run's folder checked, or cleared, for what another
    process may have started and finished there since it was first checked). A failure an
    earlier attempt recorded (``ERROR_FILE``) goes with the claim: this attempt decides."""
    import fcntl

    path = Path(run_dir) / RUNNING_FILE
    pid = os.getpid()
    claim = {"pid": pid, "host": socket.gethostname(), "started": process_started(pid)}
    folder = os.open(run_dir, os.O_RDONLY)
    try:
        with contextlib.suppress(OSError):  # NFS may refuse to lock a folder: the check alone
            fcntl.flock(folder, fcntl.LOCK_EX)  # released with the descriptor, also on a kill
        check_not_trained(run_dir)
        if before is not None:
            before()
        write_text(path, json.dumps(claim))
        (Path(run_dir) / ERROR_FILE).unlink(missing_ok=True)
    finally:
        os.close(folder)
    try:
        yield
    finally:  # the claim, unless another process has since claimed the folder
        try:
            if json.loads(path.read_text()) == claim:
                path.unlink()
        except (OSError, ValueError):
            pass


class RunBeingTrained(ConfigError):
    """Another live process trains the run: not this one's failure, nor the run's."""


def check_not_trained(run_dir: Path, who: str | None = None, by: str = "") -> None:
    """``RunBeingTrained`` when another live process trains the run (``who``, default its
    folder; ``by``: who that may be): two writers would interleave its files."""
    pid = training_worker(run_dir)
    if pid is not None:
        raise RunBeingTrained(
            f"{who or run_dir} is being trained by process {pid}{by}; let it finish or stop it "
            "first"
        )


def check_not_training(sweep_dir: Path, name: str) -> None:
    """ConfigError when a live worker trains the run ``name``: it is not to be changed now."""
    check_not_trained(run_path(sweep_dir, name), f"run {name} in {sweep_dir}")


def run_state(run_dir: Path) -> RunState:
    if (run_dir / SUMMARY).is_file() and not _summed_short(run_dir):
        return "done"
    if (run_dir / CHECKPOINT).is_file():
        return "resumable"
    return "new"


def _summed_short(run_dir: Path) -> bool:
    """A summary of fewer interactions than the run is set to, beside a checkpoint to go on
    from: an extension stopped before it trained (earlier versions left it so), not a finished
    run."""
    if not (run_dir / CHECKPOINT).is_file():
        return False
    with contextlib.suppress(OSError, ValueError, KeyError, TypeError):
        summed = json.loads((run_dir / SUMMARY).read_text())["interactions"]
        return int(summed) < int(json.loads((run_dir / CONFIG).read_text())["run"]["interactions"])
    return False


def check_existing(sweep_dir: Path, planned: PlannedRun) -> None:
    """An existing run directory must hold the same run (else resuming it would mix two); how
    often it is saved may differ (it changes no number the run logs, as ``collect`` holds)."""
    path = run_path(sweep_dir, planned.name)
    if not (path / CONFIG).is_file():
        return
    on_disk = recorded_run(path)
    planned_dict = json.loads(json.dumps(planned.config.to_dict()))
    found = run_differences(on_disk, planned_dict, ("checkpoint_every",))
    diffs = [f"{k}: {shown_value(k, a)} on disk, {shown_value(k, b)} now" for k, a, b in found]
    held, asked = on_disk.get("interactions"), planned.config.interactions
    only_length = len(diffs) == 1 and isinstance(held, int)
    a_sweep = (Path(sweep_dir) / SWEEP_FILE).is_file()  # a collection has no record to resume
    if only_length and held > asked:
        resume = f"; the recorded sweep: sili sweep --resume {shell_path(sweep_dir)}"
        resume = f"{resume} --interactions {held}" if a_sweep else ""
        raise ConfigError(
            f"run {planned.name} in {sweep_dir} has {held} interactions, more than the "
            f"{asked} asked for now (a run is never shortened); ask for {held} (--interactions "
            f"{held}{resume})"
        )
    if only_length and held < asked and a_sweep:
        raise ConfigError(  # (a run of a collection is extended in a sweep of its own)
            f"run {planned.name} in {sweep_dir} has {held} interactions, fewer than the {asked} "
            f"asked for now; extend the sweep's runs first (sili sweep --resume "
            f"{shell_path(sweep_dir)} --interactions {asked}), then run this again"
        )
    if diffs:
        raise ConfigError(
            f"run {planned.name} in {sweep_dir} was made with other settings ("
            + "; ".join(diffs[:4])
            + "): a sweep never mixes two runs under one name; give a new sweep another --out, "
            + f"or move that run out of {sweep_dir}"
        )


def shorter_run(sweep_dir: Path, planned: PlannedRun) -> bool:
    """Whether ``planned`` is on disk as the same run with a smaller budget, which it can go on
    from (a run of the sweep before ``--resume --interactions`` extended it). ConfigError when
    it differs otherwise, is kept without its checkpoint, or a live worker trains it."""
    path = run_path(sweep_dir, planned.name)
    if not (path / CONFIG).is_file():
        return False
    on_disk = recorded_run(path).get("interactions", planned.config.interactions)
    if not isinstance(on_disk, int) or on_disk >= planned.config.interactions:
        return False
    shorter = replace(planned.config, interactions=on_disk)
    check_existing(sweep_dir, replace(planned, config=shorter))  # the same run otherwise
    check_resumable(path)
    check_not_training(sweep_dir, planned.name)
    return True


def write_invocations(sweep_dir: Path, specs: list[SweepSpec]) -> None:
    """Replace the sweep's record with ``specs`` (the recorded ones, extended)."""
    entries = [json.loads(json.dumps(spec.to_dict())) for spec in specs]
    path = Path(sweep_dir) / SWEEP_FILE
    write_text(path, json.dumps({"invocations": entries}, indent=2), shared=True)


def record_invocation(sweep_dir: Path, spec: SweepSpec) -> None:
    """Append ``spec`` to ``sweep.json`` unless the same spec is already there."""
    path = Path(sweep_dir) / SWEEP_FILE
    data = read_json(path, DAMAGED_SWEEP, "invocations") if path.is_file() else {"invocations": []}
    entry = json.loads(json.dumps(spec.to_dict()))
    if entry not in data["invocations"]:
        data["invocations"].append(entry)
    write_text(path, json.dumps(data, indent=2), shared=True)


def recorded_specs(sweep_dir: Path) -> list[SweepSpec]:
    path = Path(sweep_dir) / SWEEP_FILE
    if not path.is_file():
        raise ConfigError(
            f"{sweep_dir} is not a sweep directory (no {SWEEP_FILE}); give a directory written "
            "by `sili sweep --out`"
        )
    invocations = read_json(path, DAMAGED_SWEEP, "invocations")["invocations"]
    if not isinstance(invocations, list) or not invocations:
        raise ConfigError(f"{path} is damaged (no invocation recorded); {DAMAGED_SWEEP}")
    try:
        specs = [SweepSpec.from_dict(d) for d in invocations]
        for spec in specs:
            expand(spec)  # each run's config built: a value no run can have (a hand edit)
        return specs
    except ConfigError as err:  # named with the file: the value is in it, not on the command line
        raise ConfigError(f"{path} records a sweep that cannot run: {err}") from None
    except (TypeError, AttributeError, KeyError, ValueError) as err:
        damage = f"{type(err).__name__}: {err}"
        raise ConfigError(f"{path} is damaged ({damage}); {DAMAGED_SWEEP}") from None


@contextlib.contextmanager
def sweep_lock(sweep_dir: Path) -> Iterator[None]:
    """One sweep process per directory: two would train the same runs at once."""
    Path(sweep_dir).mkdir(parents=True, exist_ok=True)
    with open(Path(sweep_dir) / LOCK, "w") as f:
        try:
            fcntl.flock(f, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise ConfigError(
                f"another `sili sweep` is running in {sweep_dir}; wait for it or stop it first"
            ) from None
        try:
            yield
        finally:
            fcntl.flock(f, fcntl.LOCK_UN)
