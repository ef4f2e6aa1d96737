"""A user's own class by ``package.module:ClassName``: a task, or a research add-on.

The module is imported from the current directory too (a console script, unlike
``python -m``, leaves it off ``sys.path``), so a run of a user's class is trained, resumed and
evaluated from a folder its module imports from.
"""

from __future__ import annotations

import importlib
import os
import sys
from typing import Any

from sili_robots.errors import ConfigError


def load_class(path: str, base: type, kind: str, instead: str = "") -> type:
    """The ``base`` subclass ``path`` names, or ConfigError saying what is wrong (``kind``: what
    it is, e.g. "task"; ``instead``: what else may be given, e.g. "a registered task or ")."""
    module_name, _, class_name = path.partition(":")
    if not module_name or not class_name:
        raise ConfigError(
            f"{kind} {path!r} names no {'module' if not module_name else 'class'}: give "
            f"{instead}package.module:ClassName"
        )
    if os.getcwd() not in sys.path:
        sys.path.append(os.getcwd())
    where = (  # (also when a run's record names it: nothing was given then)
        f"it must be {instead}package.module:ClassName of a subclass of {base.__name__} "
        "importable from the current directory or PYTHONPATH (a run of one is trained, resumed, "
        "evaluated and loaded from a folder its module imports from)"
    )
    try:
        obj: Any = importlib.import_module(module_name)
    except Exception as err:  # a module that is missing, fails to compile or raises on import
        if not (
            isinstance(err, ModuleNotFoundError) and f"{module_name}.".startswith(f"{err.name}.")
        ):
            where = f"importing {module_name} failed: fix it, or install what it imports"
        raise ConfigError(_unloadable(path, kind, module_name, err, where)) from None
    try:
        for part in class_name.split("."):
            obj = getattr(obj, part)
    except AttributeError as err:
        raise ConfigError(_unloadable(path, kind, module_name, err, where)) from None
    if not (isinstance(obj, type) and issubclass(obj, base)):
        raise ConfigError(f"{path!r} is not a subclass of {base.__name__}")
    return obj


def class_path(cls: type) -> str:
    """``package.module:ClassName`` of ``cls``: how a run records a user's class, which
    ``load_class`` reads back."""
    return f"{cls.__module__}:{cls.__qualname__}"


def _unloadable(path: str, kind: str, module_name: str, err: Exception, where: str) -> str:
    if module_name == "__main__":
        where = "a class defined in a script loads only in that script: put it in a module" + (
            ", or pass the task instance (SILI.load(path, env=...))" if kind == "task" else ""
        )
    why = str(err) if isinstance(err, ImportError) else f"{type(err).__name__}: {err}"
    return f"cannot load {kind} class {path!r} ({why}); {where}"
