"""How results are named and grouped for people: the figures, `sili runs` and the verdict share
them (a module of its own so none pulls in another's libraries)."""

import re
import shlex
from pathlib import Path

#: how the paper writes each method
METHOD_NAMES = {
    "sili": "SILI",
    "oracle": "Oracle",
    "lili": "LILI",
    "stable": "Stable",
    "sac": "SAC",
    "smirl": "SMiRL",
}

#: what sets one variant of a task's runs apart from another: one curve, one row of `sili runs`
#: (two versions of a task are never averaged together)
VARIANT_KEYS = (
    "method",
    "profile",
    "config_beta",
    "beta_scheduled",
    "controller",
    "task_args",
    "latent",
    "task_id",
)


def shell_path(path: Path | str) -> str:
    """``path`` as a command to copy takes it back: quoted for a shell, and a relative name that
    begins with "-" as ``./-name`` (an option parser would read it as an option)."""
    text = str(path)
    return shlex.quote(f"./{text}" if text.startswith("-") else text)


def file_stem(task: str) -> str:
    """``task`` as a file or folder name: a registered task's name as it is (``circle-3``), a
    user's class path with dashes for its dots and colon (``mylab-tasks-MyEnv``), which shells,
    make and LaTeX take as they are."""
    return re.sub(r"[^A-Za-z0-9_-]+", "-", task)
