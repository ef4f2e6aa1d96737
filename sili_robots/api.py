"""The Python API, in stable-baselines3's shape: ``SILI(env).learn(n)``, ``predict``,
``save`` and ``SILI.load`` (``predict`` returns the action alone, greedy by default, for one
observation: the agent's latent follows the interactions played on ``model.env``).

A model is a run directory (config, metrics, checkpoint) plus the agent and environment it
describes, so a model trained here loads in ``sili eval`` and a run of ``sili train`` loads
here. ``predict`` acts on the agent's latent, which it carries across interactions when the
interactions are played on ``model.env`` (as ``sili eval`` does): resetting ``model.env`` hands
the agent the interaction just played, from which it infers z^{j+1}.

    from sili_robots import SILI
    model = SILI("sili/Circle3-v1", method="sili", seed=0)
    model.learn(interactions=300, progress_bar=True)
    obs, info = model.env.reset()
    action = model.predict(obs, deterministic=True)
"""

from __future__ import annotations

import functools
import os
import shutil
import tempfile
import warnings
import weakref
from pathlib import Path
from typing import Any, NoReturn

import gymnasium as gym
import numpy as np
import torch

from sili_robots.agent import SILIAgent
from sili_robots.agent.config import LARGEST_INT
from sili_robots.build import (
    build_agent,
    canonical_task,
    make_run_config,
    make_run_env,
    observed_as,
    same_task_arguments,
    task_kwargs_of,
    task_name_of,
    unversioned_note,
)
from sili_robots.errors import (
    ConfigError,
    UnreadSettingWarning,
    check_count,
    check_flag,
    check_names,
    check_path,
    first_line,
)
from sili_robots.evaluation import AgentFeedback, check_same_task, evaluate, fitting
from sili_robots.metrics import COMPRESSED_METRICS, METRICS, MetricsWriter
from sili_robots.migrations import setting_path
from sili_robots.runs import (
    CHECKPOINT,
    CONFIG,
    MACHINE_SETTINGS,
    SUMMARY,
    RunConfig,
    check_new_run_dir,
    clear_run,
    load_checkpoint,
    make_run_dir,
    ready_new_run_dir,
    require_checkpoint,
    run_differences,
    set_target,
    shown_value,
)
from sili_robots.runs import read_config as read_run_config
from sili_robots.stopping import HeldStops
from sili_robots.sweep.state import check_not_in_a_sweep, check_not_trained, training_claim
from sili_robots.tasks import RepeatedInteractionEnv
from sili_robots.tasks.registry import check_argument_names, is_class_path, title_arguments
from sili_robots.training import resume, train


class SILI:
    """SILI or one of its baselines (``method``) on one task.

    ``env``: a task id or CLI name (``"sili/Circle3-v1"``, ``"circle-3"``), a
    ``package.module:ClassName`` of a task class, or a ``RepeatedInteractionEnv`` instance
    (a user's own task included). ``settings`` are agent settings by dotted path
    (``{"sac.lr": 1e-3, "addons.filter.eps": 0.01}``); ``run_dir`` keeps the run (default: a
    temporary directory, removed with the model): a new or empty directory, or with
    ``overwrite`` a run's, whose own files the first ``learn`` replaces (as ``sili train
    --overwrite``; ``SILI.load`` continues a run instead)."""

    def __init__(
        self,
        env: str | gym.Env,
        method: str = "sili",
        seed: int = 0,
        *,
        latent: str | None = None,
        profile: str | None = None,
        settings: dict[str, Any] | None = None,
        env_kwargs: dict[str, Any] | None = None,
        run_dir: str | Path | None = None,
        checkpoint_every: int = 50,
        overwrite: bool = False,
    ) -> None:
        self._task_env: gym.Env | None = None
        _check_arguments(env, settings, env_kwargs)
        overwrite = check_flag("overwrite", overwrite)
        if isinstance(env, gym.Env):
            if not isinstance(env.unwrapped, RepeatedInteractionEnv):
                raise ConfigError(
                    f"env {type(env.unwrapped).__name__} does not follow the repeated-interaction "
                    "contract; give a RepeatedInteractionEnv (see README, 'Your own task')"
                )
            if env_kwargs:
                raise ConfigError(
                    "env_kwargs apply to a task built by name; this instance was built with "
                    f"{_built_with(env)}: give its arguments to its constructor"
                )
            self._task_env, task = env, task_name_of(env)
            env_kwargs = task_kwargs_of(env)
            note = unversioned_note(type(env.unwrapped)) if is_class_path(task) else ""
        else:
            task = canonical_task(env)
            check_argument_names(task, env_kwargs or {}, "env_kwargs")
            note = unversioned_note(task)
        if note:
            warnings.warn(note, UserWarning, stacklevel=2)
        cfg = make_run_config(
            task,
            method,
            seed,
            0,
            latent=latent,
            profile=profile,
            settings=settings,
            env_kwargs=env_kwargs,
            checkpoint_every=checkpoint_every,
        )
        given = {setting_path(name): name for name in settings or {}}
        for path, why in cfg.unread_settings(given).items():  # recorded all the same
            unread = f"setting {given[path]!r} does nothing here: {why}"
            warnings.warn(unread, UnreadSettingWarning, stacklevel=2)
        if run_dir is None:  # removed with the model, unless saved or loaded where it is
            run_dir = tempfile.mkdtemp(prefix="sili-run-")
            _remove_with(self, Path(run_dir))
        else:
            # the folder given, wherever the process goes (os.chdir) since
            run_dir = check_path("run_dir", run_dir).absolute()
            check_not_in_a_sweep(run_dir, "run_dir")
        self.run_dir, self._overwrite = Path(run_dir), overwrite
        self._saved: dict[Path, tuple] = {}  # where this model saved, and what it left there
        self._check_run_dir()
        self.cfg = cfg
        self._setup(None)

    def _check_run_dir(self, clear: bool = False) -> None:
        """A new model never trains over a run or into a folder of other files (the CLI's rule);
        ``clear``: with ``overwrite``, the run there removed (``ready_new_run_dir``)."""
        load = f"SILI.load({str(self.run_dir)!r})"
        check = ready_new_run_dir if clear else check_new_run_dir
        check(self.run_dir, self._overwrite, out="run_dir", replace="overwrite=True", resume=load)

    # ------------------------------------------------------------------ building
    def _setup(self, state: dict[str, Any] | None) -> None:
        """The environment as the method observes it, and the agent (from ``state``)."""
        if self._task_env is not None:
            base = observed_as(self._task_env, self.cfg)
        else:
            base = make_run_env(self.cfg, None if state is None else self.run_dir)
        self.agent: SILIAgent = build_agent(self.cfg, base)
        game, seed = None, self.cfg.seed  # a new model's game: its training's first
        if state is not None:
            self.agent.load_state_dict(state["agent"])
            game, seed = state["game"], None
        if isinstance(getattr(self, "env", None), AgentFeedback):  # the one a user may hold
            self.env.rebind(base, self.agent, game, seed)
        else:
            self.env: gym.Env = AgentFeedback(base, self.agent, game, seed)
        #: the checkpoint's interaction this model holds, and what its run's files were then
        self._done = 0 if state is None else int(state["interaction"])
        self._loaded = None if state is None else _stamp(self.run_dir)
        self._made = self.cfg.to_dict()  # the settings it holds (``_check_config_unchanged``)

    def _reload(self, same_run: bool = False) -> None:
        """The model as its run's last checkpoint (ConfigError saying why when there is none);
        ``same_run``: refused if the folder now holds another run (``_check_same_run``)."""
        state = require_checkpoint(self.run_dir)
        cfg = read_run_config(self.run_dir)
        if same_run:
            self._check_same_run(cfg, int(state["interaction"]))
        self.close()
        self.cfg = cfg
        self._setup(state)

    def _refresh(self) -> None:
        """Catch up with a run trained further since this model loaded it (by another model
        of the same run, or ``sili train --resume``), so counts and saves start from it; torch's
        global random state stays the caller's (reloading sets the checkpoint's)."""
        if self._done and _stamp(self.run_dir) != self._loaded:
            with torch.random.fork_rng(devices=[]):
                self._reload(same_run=True)

    def _check_same_run(self, cfg: RunConfig, interaction: int) -> None:
        """A run made anew in this model's folder (``overwrite=True``, ``sili train
        --overwrite``) is not the model's to go on with: it would become another method's, or
        count from fewer interactions, without a word. Settings of the machine (kernels,
        threads) may differ: a run goes on elsewhere with them."""
        why = _changes(cfg.to_dict(), self._made, {"interactions", *MACHINE_SETTINGS})
        if interaction < self._done:
            why.insert(0, f"{interaction} trained, not {self._done} or more")
        if why:
            raise ConfigError(
                f"the run in {self.run_dir} was replaced since this model loaded it "
                f"({'; '.join(why)}): "
                f"SILI.load({str(self.run_dir)!r}) takes up the new one"
            )

    @classmethod
    def load(cls, path: str | Path, env: gym.Env | None = None) -> SILI:
        """A model saved by ``save`` or a run directory of ``sili train``; ``env``: the task
        instance to play on: the run's task built with other arguments (another controller; the
        run's horizon; it trains with its own alone), or a user's task class that cannot be
        imported by name."""
        path = check_path("path", path).absolute()
        cfg = read_run_config(path)
        state = require_checkpoint(path)
        if env is not None:
            if not isinstance(env, gym.Env):
                raise ConfigError(f"env must be a task instance (or None), got {env!r}")
            check_same_task(path, cfg, env)
        model = cls.__new__(cls)
        model.cfg, model.run_dir, model._task_env, model._overwrite = cfg, path, env, False
        model._saved = {}
        with fitting(path, cfg, env):
            model._setup(state)
        _keep_temporary(path)  # another model's temporary run, now the user's to keep
        return model

    # ------------------------------------------------------------------ sb3 API
    def learn(self, interactions: int, progress_bar: bool = False) -> SILI:
        """Train ``interactions`` more interactions from the model's checkpoint, in
        ``run_dir`` (a loaded run trains where it lies). Stopped (Ctrl-C) or failed, the model
        is its run's last checkpoint, and the next ``learn`` counts from there."""
        progress_bar = check_flag("progress_bar", progress_bar)
        self._check_config_unchanged()
        self._refresh()
        done = self._done
        interactions = check_count("interactions", interactions, high=LARGEST_INT - done)
        if done == 0:  # as when the model was made (nothing came in since), before any change
            self._check_run_dir()
        check_not_trained(self.run_dir)  # overwrite=True too: never under a trainer
        self._check_own_task()
        make_run_dir(self.run_dir, "run_dir")  # before the model changes
        if self._task_env is None:
            self.env.close()  # training builds its own (libsumo holds one simulation)
        target = done + interactions
        env = None if self._task_env is None else observed_as(self._task_env, self.cfg)
        threads = torch.get_num_threads()  # training sets the run's; the caller's come back
        # a new model's folder again with the claim: a run may have started and ended there
        ready = functools.partial(self._check_run_dir, clear=True) if done == 0 else None
        claimed = False
        try:
            with training_claim(self.run_dir, before=ready):
                claimed = True
                if done == 0:
                    self.cfg.interactions = target
                    train(self.cfg, self.run_dir, progress=progress_bar, env=env)
                else:
                    if target < self.cfg.interactions:  # a learn stopped short set more
                        set_target(self.run_dir, target)
                    self.cfg.interactions = target
                    if env is None:
                        resume(self.run_dir, progress_bar, target)
                    else:
                        train(self.cfg, self.run_dir, resume=True, progress=progress_bar, env=env)
        finally:
            with HeldStops():  # a Ctrl-C pressed again here left the model before its training
                torch.set_num_threads(threads)
                # a new model again: stopped before its first checkpoint, or refused (another
                # process trains there, whose files stay)
                new = done == 0 and (not claimed or not (self.run_dir / CHECKPOINT).is_file())
                if new and claimed:
                    clear_run(self.run_dir)
                if new:
                    self.cfg.interactions = 0
                    self._setup(None)
                else:
                    self._reload()
        return self

    def _check_own_task(self) -> None:
        """A loaded run trains on its own task only: one given to ``load`` with other arguments
        (another controller) plays it, but the run would not record them."""
        if self._task_env is None or self._done == 0:
            return  # built from the run's record, or recorded from the instance itself
        if not same_task_arguments(self._task_env, self.cfg.env_kwargs):
            given = task_kwargs_of(self._task_env)
            own = title_arguments(self.cfg.task_id or self.cfg.task, self.cfg.env_kwargs)
            raise ConfigError(
                f"the run in {self.run_dir} was trained with {own}; env, built "
                f"with {given}, can play it but not train it (the run records one task): "
                "load it without env, or with an instance built as the run says"
            )

    def predict(self, obs: np.ndarray, deterministic: bool = True) -> np.ndarray:
        """The action (alone; greedy unless ``deterministic=False``) for one observation of
        the interaction being played on ``model.env``."""
        deterministic = check_flag("deterministic", deterministic)
        if isinstance(obs, tuple) and len(obs) == 2 and isinstance(obs[1], dict):
            raise ConfigError("obs is reset()'s (obs, info) pair; give its obs alone")
        if isinstance(obs, torch.Tensor):  # one a user's network made: its graph is not ours
            obs = obs.detach().to("cpu", torch.float32)  # (numpy has no bfloat16)
        try:
            obs = np.asarray(obs, np.float32)
        except (TypeError, ValueError, RuntimeError) as exc:  # torch's: a list of graph tensors
            raise ConfigError(
                f"obs {obs!r} is not an array of numbers ({exc}); give one observation of model.env"
            ) from None
        expected = self.env.observation_space.shape
        if not np.isfinite(obs).all():
            raise ConfigError(f"obs {obs} is not finite; the agent acts on finite observations")
        if obs.shape[1:] == expected:
            raise ConfigError(
                f"obs is a batch of {obs.shape[0]}; predict takes one observation (the agent's "
                "latent follows the interactions played on model.env)"
            )
        if obs.shape != expected:
            raise ConfigError(
                f"obs has shape {obs.shape}; this model observes shape {expected} "
                "(model.env.observation_space: play the interactions on model.env)"
            )
        return self.agent.act(obs, deterministic=deterministic)

    def save(self, path: str | Path, overwrite: bool = False) -> Path:
        """Copy the run (config, metrics, checkpoint, summary) to ``path``: a new or empty
        directory, or one this model saved to before (replaced, as stable-baselines3's ``save``
        replaces its file); another run there is replaced only with ``overwrite``."""
        self._refresh()
        self._check_trained("save")
        try:
            path = check_path("save path", path).absolute()
            overwrite = check_flag("overwrite", overwrite)
            self._copy_to(path, overwrite)
        except (ConfigError, OSError) as exc:  # a script ends here: its training must stay
            own = Path(self.run_dir).resolve()
            if own not in _TEMPORARY and own not in _KEPT:
                raise
            _keep_temporary(self.run_dir)
            _KEPT.add(own)
            raise ConfigError(
                f"{exc if isinstance(exc, ConfigError) else first_line(exc)}; the model's "
                f"training is kept in {self.run_dir} "
                f"(SILI.load({str(self.run_dir)!r}) continues it)"
            ) from exc
        own = self.run_dir.resolve()
        if own in _KEPT and path.resolve() != own:  # saved after all, and loaded by no other
            _KEPT.discard(own)
            _remove_with(self, self.run_dir)
        _keep_temporary(path)
        self._saved[path.resolve()] = _stamp(path)
        return path

    def _copy_to(self, path: Path, overwrite: bool) -> None:
        if path.exists() and not path.is_dir():
            raise ConfigError(f"cannot save to {path}: it is a file; give a directory")
        if self.run_dir.resolve() in path.resolve().parents:  # a temporary run's: removed with it
            raise ConfigError(
                f"cannot save to {path}: it is inside the model's own run, {self.run_dir}; give "
                "a directory outside it"
            )
        if path.resolve() != self.run_dir.resolve():
            # its own earlier save, as it left it (not since replaced or trained on by another)
            replace = overwrite or self._saved.get(path.resolve()) == _stamp(path)
            check_new_run_dir(
                path,
                replace,
                out="save()",
                replace="save(path, overwrite=True)",
                resume=f"SILI.load({str(path)!r})",
            )
            if replace:  # nothing of the replaced run stays to mix with this one
                clear_run(path)
            path.mkdir(parents=True, exist_ok=True)
            for name in (CONFIG, METRICS, CHECKPOINT, SUMMARY, COMPRESSED_METRICS):
                if (self.run_dir / name).is_file():
                    shutil.copy2(self.run_dir / name, path / name)
            if (path / METRICS).is_file():  # the checkpoint's rows only (a stop writes more)
                MetricsWriter(path, self.cfg.metric_columns(), keep_rows=self._done).close()

    def evaluate(self, interactions: int = 100) -> dict[str, Any]:
        """Greedy play continuing the saved game: mean task reward, and stability after the first
        interaction (``sili eval``'s numbers, ``evaluation.evaluate``). ``model.env``
        starts again from the saved game afterwards (the evaluation plays on the same task:
        libsumo holds one simulation per process); torch's global random state is the caller's
        again (the evaluation and the reload set the checkpoint's)."""
        interactions = check_count("interactions", interactions)
        with torch.random.fork_rng(devices=[]):
            self._refresh()
            self._check_trained("evaluate")
            self.close()
            try:
                return evaluate(self.run_dir, interactions, self._task_env)
            finally:
                self._setup(load_checkpoint(self.run_dir))

    def close(self) -> None:
        """Close ``model.env`` (a task instance given to ``SILI`` stays open: it is yours)."""
        if self._task_env is None:
            self.env.close()

    def _check_trained(self, what: str) -> None:
        if self.cfg.interactions == 0 or not (self.run_dir / CHECKPOINT).is_file():
            raise ConfigError(f"nothing to {what} yet: call learn() first")

    def _check_config_unchanged(self) -> None:
        """``model.config`` changed by hand: its agent was built from the settings it was made
        with, and a reload put those back, so an edit was used or dropped by chance."""
        changed = _changes(self.cfg.to_dict(), self._made, {"interactions"})
        if changed:
            raise ConfigError(
                f"model.config was changed since the model was made or loaded "
                f"({'; '.join(changed)}): a model's settings are given when it is made "
                "(SILI(..., settings=...)); make a new model to train with others"
            )

    @property
    def config(self) -> RunConfig:
        """The run's settings, to read: ``learn`` refuses a config changed by hand."""
        return self.cfg

    @property
    def trained_interactions(self) -> int:
        """The interactions the model holds have trained (``config.interactions`` is the target
        of the last ``learn``, which a Ctrl-C may have stopped short of). Reading it changes
        nothing: the run trained further elsewhere is taken up by the next ``learn``, ``save``
        or ``evaluate``, as ``predict`` and ``model.env`` keep the model's until then."""
        return self._done

    def __copy__(self) -> NoReturn:
        raise TypeError(
            "a SILI model is its run directory and simulation, which a copy would share: "
            "save it and SILI.load the saved copy"
        )

    def __deepcopy__(self, memo: dict) -> NoReturn:
        self.__copy__()

    def __reduce_ex__(self, protocol: object) -> NoReturn:
        """A pickled model is a copy too: unpickled, it shared the run (a temporary one was
        removed with the first)."""
        self.__copy__()


def _changes(now: dict[str, Any], made: dict[str, Any], ignoring: set[str]) -> list[str]:
    """``key now, not made`` for the first 3 settings (the method before its settings) in which
    the config ``now`` differs from the one a model was ``made`` with, "..." for the rest."""
    found = sorted(run_differences(now, made, ignoring), key=lambda d: d[0].count("."))
    why = [f"{key} {shown_value(key, a)}, not {shown_value(key, b)}" for key, a, b in found]
    return [*why[:3], "..."] if len(why) > 3 else why


#: temporary run directories of live models, removed with their model
_TEMPORARY: dict[Path, weakref.finalize] = {}
#: temporary runs a refused save kept (the error named them), until their model saves or another
#: model loads them
_KEPT: set[Path] = set()


def _built_with(env: gym.Env) -> str:
    """The arguments a task instance was given (less its registered version's own); a
    ConfigError of its own when it cannot be recorded at all (wrapped, another variant)."""
    if getattr(env.unwrapped, "init_kwargs", None) is None:
        return "positional arguments"
    return str(task_kwargs_of(env) or "its default arguments")


def _check_arguments(env: object, settings: object, env_kwargs: object) -> None:
    """What ``SILI(...)`` takes, named, instead of an error from deep inside."""
    if not isinstance(env, str | gym.Env):
        hint = " (a class: give an instance, or its 'package.module:ClassName')"
        raise ConfigError(
            "env must be a task name or id ('circle-3', 'sili/Circle3-v1'), a "
            "'package.module:ClassName' or a task instance, got "
            f"{env!r}{hint if isinstance(env, type) else ''}"
        )
    for name, given in (("settings", settings), ("env_kwargs", env_kwargs)):
        if given is not None:
            check_names(name, given)


def _remove_with(model: SILI, run_dir: Path) -> None:
    """``run_dir``, a temporary run, removed when ``model`` goes."""
    _TEMPORARY[run_dir.resolve()] = weakref.finalize(model, _remove_temporary, run_dir, os.getpid())


def _remove_temporary(path: Path, owner: int) -> None:
    _TEMPORARY.pop(path.resolve(), None)
    if os.getpid() == owner:  # not a forked child's copy of the model
        shutil.rmtree(path, ignore_errors=True)


def _keep_temporary(path: Path) -> None:
    """A temporary run saved or loaded where it is stays after its model."""
    _KEPT.discard(Path(path).resolve())  # loaded or saved where it is: the user's now
    finalizer = _TEMPORARY.pop(Path(path).resolve(), None)
    if finalizer is not None:
        finalizer.detach()


def _stamp(run_dir: Path) -> tuple:
    """What identifies the files a save left in ``run_dir``: any rewrite changes an inode or a
    change time (which, unlike a modification time, a copy cannot carry over)."""
    stats = [(run_dir / name).stat() for name in (CONFIG, CHECKPOINT) if (run_dir / name).exists()]
    return tuple((s.st_ino, s.st_ctime_ns) for s in stats)
