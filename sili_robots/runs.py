"""Run directories: the resolved config, checkpoints, and the files that say a run's state.

A run directory holds ``config.json`` (everything needed to rebuild the run, plus package
versions: ``provenance``), ``metrics.csv`` (one row per interaction: ``metrics``),
``checkpoint.pt`` (written atomically every ``checkpoint_every`` interactions) and, once
finished, ``summary.json``.
"""

from __future__ import annotations

import contextlib
import errno
import io
import json
import math
import numbers
import pickle
import re
import shutil
from collections.abc import Collection
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import gymnasium as gym
import torch

from sili_robots.addons.config import AddonsConfig
from sili_robots.agent.config import LARGEST_INT, AgentConfig, set_path
from sili_robots.agent.config import check as check_ranges
from sili_robots.atomic import write_bytes, write_text
from sili_robots.errors import ConfigError, check_count, check_seed, first_line, is_number
from sili_robots.metrics import (
    COMPRESSED_METRICS,
    ID_COLUMNS,
    METRIC_COLUMNS,
    METRICS,
    ROW_COLUMNS,
)
from sili_robots.migrations import migrate_agent_state, migrate_run, setting_path
from sili_robots.plugins import class_path
from sili_robots.provenance import OWN_CODE, REVISION, source_digests, versions
from sili_robots.tasks.registry import (
    check_argument_names,
    is_class_path,
    task_class,
    task_spec,
    without_defaults,
)

CONFIG, CHECKPOINT, SUMMARY = "config.json", "checkpoint.pt", "summary.json"
#: the folder of a sweep or a collection that holds its run directories
RUNS_DIR = "runs"
#: what to do about a damaged file (``read_json``)
DAMAGED_CONFIG = "it is not a run's config: train the run again"
DAMAGED_SUMMARY = (
    "delete it, then resume the run from its checkpoint (sili train --resume or sili sweep "
    "--resume), or collect a collected one again"
)


#: the most torch threads a run may ask for (more than any processor's cores; far more fail in
#: OpenMP's thread creation, without a word of which setting asked)
MAX_THREADS = 1024


@dataclass
class RunConfig:
    """One training run, fully resolved."""

    task: str
    method: str
    seed: int
    interactions: int
    agent: AgentConfig
    addons: AddonsConfig = field(default_factory=AddonsConfig)
    env_kwargs: dict[str, Any] = field(default_factory=dict)
    checkpoint_every: int = 50
    #: torch threads of the run's arithmetic; a second thread sums in another order, so it is
    #: part of what makes a run reproducible (sweep workers keep 1 each)
    threads: int = 1
    #: the gymnasium id (task version) the run builds; resolved from ``task`` when the run is
    #: configured and recorded, so the run keeps its version when the name moves on
    task_id: str | None = None

    def __post_init__(self) -> None:
        from sili_robots.agent.methods import PRESETS

        self.seed = check_seed(self.seed)
        for name, low, high in (
            ("interactions", 0, LARGEST_INT),
            ("checkpoint_every", 1, LARGEST_INT),
            ("threads", 1, MAX_THREADS),
        ):
            setattr(self, name, check_count(name, getattr(self, name), low, high))
        if self.method not in PRESETS:
            raise ConfigError(f"unknown method {self.method!r}; allowed: {', '.join(PRESETS)}")
        if not isinstance(self.env_kwargs, dict) or not isinstance(self.task, str):
            raise ConfigError(
                f"task must be a name and env_kwargs an object of its arguments, got "
                f"{self.task!r} and {self.env_kwargs!r}"
            )
        if self.task_id is None:
            from sili_robots.tasks import task_spec

            # an unknown task fails, with the choices, where the task is built
            with contextlib.suppress(ConfigError):
                self.task_id = task_spec(self.task).gym_id

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["agent"] = self.agent.to_dict()
        d["addons"] = self.addons.to_dict()
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> RunConfig:
        """Read a recorded config (any earlier layout); one recorded before task versions ran
        the task's first."""
        d = dict(migrate_run(d))
        d["agent"] = AgentConfig.from_dict(d["agent"])
        check_ranges(d["agent"], "")  # a damaged value named here (with the file), not in use
        d["addons"] = AddonsConfig.from_dict(d.get("addons", {}))
        if d.get("task_id") is None:
            d["task_id"] = recorded_task_id(d)
        return cls(**d)

    def unread_settings(self, given: Collection[str]) -> dict[str, str]:
        """The settings among ``given`` (dotted paths) this run never reads or that do nothing
        here, and why: recorded all the same, so a reader is told (a sweep gives its settings
        to every method, so they are not refused)."""
        from sili_robots.agent.methods import unused_settings

        return {**unused_settings(self.agent, given), **self.addons.unread(given, self.agent)}

    def metric_columns(self, new_run: bool = False) -> tuple[str, ...]:
        """``metrics.csv``'s columns: ``METRIC_COLUMNS``, then those its own add-ons declare.
        ``new_run``: two add-ons declaring one column are refused (the second's values replaced
        the first's; a run recorded so goes on as it began)."""
        own: dict[str, str] = {}  # column -> the add-on that declares it
        for cls in self.addons.plugin_classes():
            path, declared = class_path(cls), cls.metric_columns
            if not isinstance(declared, tuple | list) or not all(
                isinstance(c, str) and c.strip() for c in declared
            ):
                raise ConfigError(
                    f"add-on {path} declares metric_columns {declared!r}; give a tuple of column "
                    "names, e.g. ('score',)"
                )
            taken = [c for c in declared if c in METRIC_COLUMNS]
            if taken:
                raise ConfigError(
                    f"add-on {path} declares metric_columns {', '.join(taken)}, which metrics.csv "
                    "has already; name its own otherwise"
                )
            table = [c for c in declared if c in (*ID_COLUMNS, *ROW_COLUMNS)]
            if table and new_run:  # results.csv's own values would replace the add-on's
                raise ConfigError(
                    f"add-on {path} declares metric_columns {', '.join(table)}, which a sweep's "
                    "results.csv has already; name its own otherwise"
                )
            shared = [f"{c} ({own[c]})" for c in declared if c in own]
            if shared and new_run:
                raise ConfigError(
                    f"add-on {path} declares metric_columns {', '.join(shared)}, which another "
                    "add-on of the run declares already; give each add-on its own column names"
                )
            own.update({c: path for c in declared if c not in own})
        return (*METRIC_COLUMNS, *own)

    def provenance(self) -> dict[str, str]:
        """The software and processor the run uses now (``provenance.versions``), with the code
        of the classes it names by ``module:Class``: its task (unless it cannot be imported
        by its name: a class of a script, trained as an instance), its add-ons."""
        own = []
        if is_class_path(self.task):
            with contextlib.suppress(ConfigError):
                own.append(task_class(self.task))
        return {**versions(self.threads), **source_digests([*own, *self.addons.plugin_classes()])}

    def set(self, name: str, value: Any) -> None:
        """Set an agent or add-on setting by dotted path (or an earlier flat name)."""
        path = setting_path(name)
        if path.startswith("addons."):
            set_path(self.addons, path.removeprefix("addons."), value, prefix="addons.")
        else:
            set_path(self.agent, path, value)


def recorded_task_id(run: dict[str, Any]) -> str | None:
    """The task version a recorded run config (``config.json``'s ``run``) built: its ``task_id``,
    or, for a config written before versions were recorded, its task's first version."""
    from sili_robots.tasks.registry import first_version

    if run.get("task_id"):
        return str(run["task_id"])
    try:
        return first_version(run["task"]).gym_id
    except ConfigError:
        return None


#: written by a failed sweep run (the traceback or how its worker died); removed when it succeeds
ERROR_FILE = "error.txt"
#: written by the process that trains a run (``sili train``, a sweep worker, ``SILI.learn``):
#: {"pid": ..., "host": ..., "started": boot id and start time, which tell a reused pid}
RUNNING_FILE = "worker.json"
#: written by a sweep that is stopping: its worker stops once the interaction it is in is saved
STOP_FILE = "stop"
#: a sweep run's TensorBoard scalars
TB_DIR = "tb"
#: what a run writes in its directory: ``--overwrite`` removes these and nothing else
RUN_FILES = (
    CONFIG,
    METRICS,
    CHECKPOINT,
    SUMMARY,
    COMPRESSED_METRICS,
    ERROR_FILE,
    RUNNING_FILE,
    STOP_FILE,
)
RUN_DIRS = (TB_DIR,)


def clear_run(run_dir: Path) -> None:
    """Remove a run's own files from ``run_dir``, leaving anything else a user put there; its
    config last, so a removal cut short still leaves a folder that is a run's."""
    run_dir = Path(run_dir)
    for name in RUN_DIRS:
        shutil.rmtree(run_dir / name, ignore_errors=True)
    for path in run_dir.glob("*.tmp"):  # a write cut short (``atomic.replacing``)
        path.unlink(missing_ok=True)
    for name in sorted(RUN_FILES, key=lambda n: n == CONFIG):
        (run_dir / name).unlink(missing_ok=True)


def foreign_files(directory: Path, own: tuple[str, ...] = ()) -> list[str]:
    """The names in ``directory`` that are neither ``own`` nor hidden (``.lock``, ``.gitkeep``)
    nor a write cut short (``*.tmp``)."""
    return sorted(
        p.name
        for p in Path(directory).iterdir()
        if p.name not in own and not p.name.startswith(".") and not p.name.endswith(".tmp")
    )


def listed(names: list[str], most: int = 5) -> str:
    """``a, b, c, ...``: the first ``most`` names, for a message."""
    return ", ".join(names[:most]) + (", ..." if len(names) > most else "")


def check_new_run_dir(
    run_dir: Path,
    overwrite: bool = False,
    *,
    out: str = "--out",
    replace: str = "--overwrite",
    resume: str = "--resume",
) -> None:
    """A new run goes into a new or empty directory, or with ``overwrite`` a run's: a run is
    never trained over unasked, files of something else are never mixed with (or replaced by) a
    run's, and a run's files left without their config (a removal cut short) are replaced only
    with ``overwrite``. ``out``, ``replace``, ``resume``: what the caller calls the directory,
    the overwrite and the way to continue a run (the CLI's options, the API's arguments)."""
    run_dir = Path(run_dir)
    if run_dir.is_file():
        raise ConfigError(f"{run_dir} is a file; give {out} a directory (new, or empty)")
    if (run_dir / CONFIG).exists() and not overwrite:
        if not (run_dir / CHECKPOINT).exists():  # nothing to continue from
            kept = _finished_files(run_dir)
            what = (
                f"a finished run kept without its {CHECKPOINT} (it has {', '.join(kept)})"
                if kept
                else "a run with no checkpoint yet"
            )
            raise ConfigError(f"{run_dir} already holds {what}; {replace} replaces it")
        raise ConfigError(
            f"{run_dir} already holds a run; {resume} continues it, {replace} replaces it"
        )
    if run_dir.is_dir() and not (run_dir / CONFIG).exists():
        left = foreign_files(run_dir)
        if left and not overwrite and not set(left) - {*RUN_FILES, *RUN_DIRS}:
            raise ConfigError(
                f"{run_dir} holds a run's files ({', '.join(left)}) but no {CONFIG}, so it "
                f"cannot be resumed; {replace} replaces them"
            )
        others = foreign_files(run_dir, (*RUN_FILES, *RUN_DIRS))
        if others:
            raise ConfigError(
                f"{run_dir} is not a run but holds files ({listed(others)}); give {out} a new "
                "or empty directory"
            )


def ready_new_run_dir(run_dir: Path, overwrite: bool = False, **names: str) -> None:
    """``check_new_run_dir``, then with ``overwrite`` the run there removed (``clear_run``): a
    new run's folder as its trainer takes it, under the training claim (``training_claim``'s
    ``before``: nothing may start or end there between the check and the claim)."""
    check_new_run_dir(run_dir, overwrite, **names)
    if overwrite:
        clear_run(run_dir)


def make_run_dir(run_dir: Path, out: str = "--out") -> list[Path]:
    """Create a run directory, or ConfigError naming it (and ``out``, what the caller calls
    it) when it cannot be; the folders it made, innermost first."""
    made = [d for d in (Path(run_dir), *Path(run_dir).parents) if d.name != ".." and not d.exists()]
    if Path(run_dir).is_file():
        raise ConfigError(f"{run_dir} is a file; give {out} a directory (new, or empty)")
    try:
        Path(run_dir).mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise ConfigError(
            f"cannot create the run directory {run_dir}: {err.strerror or err}; "
            f"give {out} a directory that can be written"
        ) from None
    return made


def write_config(run_dir: Path, cfg: RunConfig) -> None:
    make_run_dir(run_dir)
    payload = {"run": cfg.to_dict(), "versions": cfg.provenance()}
    write_text(run_dir / CONFIG, json.dumps(payload, indent=2, sort_keys=True))


def record_continuation(run_dir: Path, cfg: RunConfig, interaction: int) -> None:
    """Note in ``config.json`` that run ``cfg`` went on at ``interaction`` with other software
    (its own classes' code too) or on another kind of processor than it last ran on: seeded runs
    repeat only on the same, so its results are then a mix (``continued``: where, and with
    what)."""
    now, changed = other_software(run_dir, cfg)
    if changed:
        path = Path(run_dir) / CONFIG
        record = read_json(path, DAMAGED_CONFIG, "run")
        record.setdefault("continued", []).append(
            {"from_interaction": interaction, "versions": now}
        )
        write_text(path, json.dumps(record, indent=2, sort_keys=True))


def other_software(
    run_dir: Path, cfg: RunConfig
) -> tuple[dict[str, str], dict[str, tuple[str | None, str | None]]]:
    """The software and processor run ``cfg`` uses now (``provenance``), and where they differ
    from what it last ran with (``config.json``'s last ``continued``, else its own record):
    ``{key: (then, now)}``, None where one side has no such key."""
    record = read_json(Path(run_dir) / CONFIG, DAMAGED_CONFIG, "run")
    now = full = cfg.provenance()
    last = (record.get("continued") or [record])[-1].get("versions") or {}
    # what one side does not know (an earlier version wrote it, or git could not tell) is no
    # difference; a class's code known on both sides but under other names is
    for known in (lambda k: k == REVISION, lambda k: k.startswith(OWN_CODE)):
        keys = [{k for k in d if known(k)} for d in (now, last)]
        if not all(keys):
            now, last = (
                {k: v for k, v in d.items() if k not in keys[0] | keys[1]} for d in (now, last)
            )
    keys = sorted(k for k in now.keys() | last.keys() if now.get(k) != last.get(k))
    return full, {k: (last.get(k), now.get(k)) for k in keys}


def set_target(run_dir: Path, interactions: int) -> None:
    """Record a new target length in ``config.json`` (the run in today's layout); the versions
    and processor stay those it began with."""
    path = Path(run_dir) / CONFIG
    record = read_json(path, DAMAGED_CONFIG, "run")
    cfg = read_config(run_dir)
    cfg.interactions = interactions
    record["run"] = cfg.to_dict()
    write_text(path, json.dumps(record, indent=2, sort_keys=True))


def read_json(path: Path, what: str, *keys: str) -> dict[str, Any]:
    """A JSON object a run or sweep wrote, with ``keys``; ConfigError naming the file when it is
    damaged (``what``: what it should be, and what to do)."""
    try:
        data = json.loads(Path(path).read_text())
    except ValueError as err:
        raise ConfigError(f"{path} is damaged ({first_line(err)}); {what}") from None
    if not isinstance(data, dict):
        raise ConfigError(f"{path} is damaged (not a JSON object); {what}")
    missing = [k for k in keys if k not in data]
    if missing:
        raise ConfigError(f"{path} is damaged (no {', '.join(missing)}); {what}")
    return data


def _give_a_run(folder: Path) -> str:
    """What to give instead of ``folder``: one of its runs that kept its checkpoint when it is a
    sweep (a collection keeps none: its sweep's runs have them)."""
    held = sorted(p.parent for p in Path(folder).glob(f"{RUNS_DIR}/*/{CONFIG}"))
    if not held:
        return "give a directory written by `sili train --out` or `SILI.save`"
    kept = [run for run in held if (run / CHECKPOINT).is_file()]
    if not kept:
        return (
            f"it holds runs without their {CHECKPOINT} (a collection): give the run in the "
            "sweep it was collected from"
        )
    return f"it is a sweep: give one of its runs, e.g. {kept[0]}"


def read_config(run_dir: Path) -> RunConfig:
    path = Path(run_dir) / CONFIG
    if not Path(run_dir).exists():
        raise ConfigError(
            f"{run_dir} does not exist; give a run directory (`sili train --out`, `SILI.save`)"
        )
    if Path(run_dir).is_file():
        own = Path(run_dir).name in (CONFIG, CHECKPOINT, METRICS, COMPRESSED_METRICS, SUMMARY)
        folder = f": give {Path(run_dir).parent}" if own else ""
        raise ConfigError(f"{run_dir} is a file, not a run directory{folder}")
    if not path.is_file():
        raise ConfigError(f"{run_dir} is not a run directory (no {CONFIG}); {_give_a_run(run_dir)}")
    data = read_json(path, DAMAGED_CONFIG, "run")
    try:
        cfg = RunConfig.from_dict(data["run"])
        if not is_class_path(cfg.task):
            task_spec(cfg.task)  # a name this package registers: the tables group runs by it
        if cfg.task_id in gym.registry:  # a registered task's arguments (a class's may change)
            check_argument_names(cfg.task_id, cfg.env_kwargs, "env_kwargs")
        return cfg
    except (ConfigError, TypeError, KeyError, AttributeError, ValueError) as err:
        import sili_robots

        why = str(err) if isinstance(err, ConfigError) else first_line(err)
        newer = _newer_writer(data, sili_robots.__version__)
        if newer is not None:  # settings this version does not know, not damage
            raise ConfigError(
                f"{path} was written by sili-robots {newer}, newer than this one "
                f"({sili_robots.__version__}), and does not read here ({why}); update "
                "sili-robots (pip install -U sili-robots) to resume or play the run"
            ) from None
        raise ConfigError(f"{path} is damaged ({why}); {DAMAGED_CONFIG}") from None


def _newer_writer(data: dict[str, Any], this: str) -> str | None:
    """The package version that wrote a ``config.json`` when it is newer than ``this``."""
    recorded = data.get("versions")
    written = recorded.get("sili_robots") if isinstance(recorded, dict) else None
    if not isinstance(written, str):
        return None

    def numbers(version: str) -> tuple[int, ...]:
        return tuple(int(n) for n in re.findall(r"\d+", version)[:3])

    return written if numbers(written) > numbers(this) else None


#: recorded settings (dotted) that pick kernels or bookkeeping for a machine, the same
#: configuration either way: another thread count or kernel sums in another order, and the
#: defaults of ``agent.matmul`` and ``agent.sac.precision`` are chosen per machine
MACHINE_SETTINGS = ("threads", "checkpoint_every", "agent.matmul", "agent.sac.precision")


def with_settings_of(cfg: RunConfig, recorded: dict[str, Any], keys: Collection[str]) -> RunConfig:
    """``cfg`` with the settings ``keys`` (dotted) of ``recorded`` (a run's config as a dict,
    e.g. ``recorded_run``), those it has: a run goes on with the kernels it was made with."""
    data = cfg.to_dict()
    for key in keys:
        *parents, leaf = key.split(".")
        source, target = recorded, data
        for part in parents:
            source, target = source.get(part, {}), target[part]
        if isinstance(source, dict) and leaf in source:
            target[leaf] = source[leaf]
    return RunConfig.from_dict(data)


def same_run(a: RunConfig, b: RunConfig, ignoring: Collection[str]) -> bool:
    """Whether two configs make the same run, whatever each has in the settings ``ignoring``
    (dotted; e.g. those a machine's timing chose)."""
    return not run_differences(a.to_dict(), b.to_dict(), ignoring)


def run_differences(
    a: dict[str, Any], b: dict[str, Any], ignoring: Collection[str] = ()
) -> list[tuple[str, Any, Any]]:
    """``differences`` of two runs' configs (``to_dict``, ``recorded_run``), where a task
    argument given at the task's default is the same run as one not given (a sweep's
    ``--controller mink`` on Sawyer-Reach, or none), but in the settings ``ignoring`` (dotted)."""
    return [d for d in differences(_as_built(a), _as_built(b)) if d[0] not in ignoring]


def shown_value(key: str, value: Any) -> str:
    """A value of ``run_differences`` as a message names it: a task argument a run was not
    given is its version's default (recorded as nothing, not None)."""
    return "its default" if value is None and key.startswith("env_kwargs.") else repr(value)


def _as_built(run: dict[str, Any]) -> dict[str, Any]:
    kwargs, task = run.get("env_kwargs"), run.get("task")
    if not (isinstance(kwargs, dict) and kwargs and isinstance(task, str)):
        return run
    task_id = run.get("task_id") if isinstance(run.get("task_id"), str) else None
    return {**run, "env_kwargs": without_defaults(task, task_id, kwargs)}


def differences(a: Any, b: Any, prefix: str = "") -> list[tuple[str, Any, Any]]:
    """(dotted key, value in ``a``, value in ``b``) for every leaf two nested dicts (two runs'
    configs) differ in, in key order."""
    if isinstance(a, dict) and isinstance(b, dict):
        out: list[tuple[str, Any, Any]] = []
        for key in sorted(set(a) | set(b)):
            out += differences(a.get(key), b.get(key), f"{prefix}{key}.")
        return out
    return [] if a == b else [(prefix[:-1], a, b)]


def save_checkpoint(run_dir: Path, state: dict[str, Any]) -> None:
    """Write atomically: a kill during the write leaves the previous checkpoint intact. Made in
    memory first: torch's own file writer reports a full disk as "unexpected pos"."""
    data = io.BytesIO()
    torch.save(state, data)
    write_bytes(Path(run_dir) / CHECKPOINT, data.getbuffer())


def _finished_files(run_dir: Path) -> list[str]:
    """The files of a finished run that ``run_dir`` holds (a kept one has them, not always its
    checkpoint)."""
    return [name for name in (SUMMARY, COMPRESSED_METRICS) if (run_dir / name).is_file()]


def check_resumable(run_dir: Path) -> None:
    """Refuse a finished run kept without its checkpoint (``sili collect``, or the checkpoint
    deleted): resuming it would train it again from the start over its results. A run killed
    before its first checkpoint has neither and starts over (its logged interactions with it)."""
    run_dir = Path(run_dir)
    if (run_dir / CHECKPOINT).is_file():
        return
    kept = _finished_files(run_dir)
    if kept:
        raise ConfigError(
            f"{run_dir} holds a finished run without its {CHECKPOINT} (it has "
            f"{', '.join(kept)}): there is no checkpoint to resume, extend or evaluate it from; "
            "train it again with --out elsewhere"
        )


def require_checkpoint(run_dir: Path) -> dict[str, Any]:
    """The last checkpoint, or ConfigError saying why there is none."""
    state = load_checkpoint(run_dir)
    if state is None:
        if not Path(run_dir).is_dir():  # removed since (a temporary run goes with its model)
            raise ConfigError(f"{run_dir} does not exist (any more): no run is there")
        check_resumable(run_dir)  # a run kept without its checkpoint says so
        raise ConfigError(f"{run_dir} has no checkpoint yet (no {CHECKPOINT}); train it first")
    return state


def recorded_run(run_dir: Path) -> dict[str, Any]:
    """A run's recorded config (config.json's "run") in today's layout, as JSON compares it:
    settings added since get their defaults; as recorded when it no longer reads."""
    raw = read_json(Path(run_dir) / CONFIG, DAMAGED_CONFIG, "run")["run"]
    try:
        run = RunConfig.from_dict(raw).to_dict()
    except (ConfigError, TypeError, KeyError):
        run = raw
    return json.loads(json.dumps(run))


#: what a run's config may say otherwise than its checkpoint: its budget (extended), its
#: machine's settings and where its add-ons' code lives (a user's module may be renamed, as a
#: task class may); the task, method and seed are checked on their own
NOT_CHECKPOINTED = (
    "interactions",
    "task",
    "task_id",
    "method",
    "seed",
    "addons.plugins",
    *MACHINE_SETTINGS,
)


def _other_settings(recorded: Any, cfg: RunConfig) -> list[tuple[str, Any, Any]]:
    """The settings in which the run a checkpoint recorded differs from ``cfg``, its task
    arguments as built (older checkpoints record none: nothing to compare)."""
    if not isinstance(recorded, dict):
        return []
    try:
        recorded = RunConfig.from_dict(recorded).to_dict()  # in today's layout, as cfg is
    except (ConfigError, TypeError, KeyError, AttributeError, ValueError):
        return []  # another version's layout: the task, method and seed were compared
    return run_differences(recorded, cfg.to_dict(), NOT_CHECKPOINTED)


#: what ``torch.load`` raises on a damaged checkpoint (and OSError EINVAL, at some cut lengths)
UNREADABLE = (pickle.UnpicklingError, RuntimeError, EOFError, ValueError, KeyError, TypeError)


def load_checkpoint(run_dir: Path) -> dict[str, Any] | None:
    """The last checkpoint (in today's layout), or None before the first."""
    path = Path(run_dir) / CHECKPOINT
    if not path.is_file():
        if path.exists():  # (not "no checkpoint yet, train it first")
            raise ConfigError(
                f"{path} is not a checkpoint file (a folder?); the run can be neither resumed "
                "nor played from it: train it again (sili train ... --overwrite)"
            )
        return None
    try:
        state = torch.load(path, weights_only=False)
        state["agent"] = migrate_agent_state(state["agent"])
    except (*UNREADABLE, OSError) as err:
        if isinstance(err, OSError) and err.errno != errno.EINVAL:
            raise  # the disk's (unreadable, refused): named as such by the command
        raise ConfigError(  # (torch's zip reader raises EINVAL at some cut lengths)
            f"{path} is damaged ({first_line(err)}); the run can be neither resumed nor "
            "played from it: train it again (sili train ... --overwrite)"
        ) from None
    cfg = read_config(run_dir)
    task = state.get("task")  # recorded since checkpoints name their task
    registered = task is not None and ":" not in task  # (a user's class may be renamed)
    theirs = [
        f"{key} {value!r}"
        for key, value, ours in (
            ("task", task if registered else None, cfg.task_id or cfg.task),
            ("method", state.get("method"), cfg.method),  # (older checkpoints name neither)
            ("seed", state.get("seed"), cfg.seed),
        )
        if value is not None and value != ours
    ]
    if theirs:
        raise ConfigError(
            f"{path} is a checkpoint of {', '.join(theirs)}, not of the run in {run_dir} "
            f"({cfg.task_id or cfg.task}, {cfg.method}, seed {cfg.seed}): was it copied from "
            "another run? Train this run again (sili train ... --overwrite)"
        )
    other = _other_settings(state.get("run"), cfg)
    if other:
        shown = "; ".join(f"{key} {theirs!r} there, {ours!r} here" for key, theirs, ours in other)
        raise ConfigError(
            f"{path} is a checkpoint of a run with other settings ({shown[:600]}), not of the run "
            f"{run_dir / CONFIG} describes: was it copied from another run, or the config "
            "edited? Train this run again (sili train ... --overwrite)"
        )
    done, wall = state.get("interaction"), state.get("wall_time")
    if not (
        isinstance(done, numbers.Integral) and is_number(done) and 0 <= done <= cfg.interactions
    ):
        raise ConfigError(  # e.g. -5: a resume went on from there and wrote over the run's rows
            f"{path} is damaged (its interaction is {done!r}, not a count within the run's "
            f"{cfg.interactions}); the run can be neither resumed nor played from it: train it "
            "again (sili train ... --overwrite)"
        )
    if not (is_number(wall) and math.isfinite(wall) and wall >= 0):
        raise ConfigError(
            f"{path} is damaged (its wall_time is {wall!r}, not a duration in seconds); the run "
            "can be neither resumed nor played from it: train it again (sili train ... --overwrite)"
        )
    return state
