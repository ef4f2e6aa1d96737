"""One sweep run inside a worker process (local pool or Ray): train or resume, never raise.

Both backends call :func:`run_job` in a process of its own (one run per process: libsumo holds
one simulation per process, and nothing of one run leaks into the next). Any failure becomes an
outcome with the error text, and ``error.txt`` in the run directory, so one bad run never stops
the sweep. This module imports torch only inside the call, after capping threads.
"""

from __future__ import annotations

import contextlib
import os
import time
import traceback
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from sili_robots.atomic import write_text
from sili_robots.runs import ERROR_FILE, STOP_FILE
from sili_robots.sweep import tensorboard
from sili_robots.sweep.state import RunBeingTrained, run_state, training_claim

#: one thread per worker: K workers share the machine's cores
THREAD_ENV = ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS")


@dataclass
class Job:
    """What a worker needs to know; plain data so it pickles for any backend."""

    name: str
    config: dict[str, Any]
    run_dir: str
    tensorboard: bool = False


@dataclass
class Outcome:
    name: str
    status: str  # "done" or "failed"
    resumed: bool = False
    error: str | None = None
    wall_time_s: float = 0.0
    pid: int = 0  # the worker process that ran it (0: none did)
    verdict: str = ""  # a finished run's one line (``sili_robots.verdict``), for people

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def limit_threads() -> None:
    for var in THREAD_ENV:
        os.environ[var] = "1"


def run_job(job: Job) -> Outcome:
    """Train (or resume, or skip when finished) one run; failures are returned, not raised."""
    limit_threads()
    t0 = time.perf_counter()
    run_dir = Path(job.run_dir)
    run_dir.mkdir(parents=True, exist_ok=True)
    state = run_state(run_dir)
    if state == "done":
        return Outcome(job.name, "done", pid=os.getpid(), verdict=_verdict(run_dir))
    try:
        with training_claim(run_dir):
            import torch

            from sili_robots.runs import RunConfig
            from sili_robots.training import train

            torch.set_num_threads(1)
            cfg = RunConfig.from_dict(job.config)
            with tensorboard.mirrored(run_dir, job.tensorboard):
                stop_file = run_dir / STOP_FILE  # how a sweep stops it
                train(cfg, run_dir, state == "resumable", progress=False, stop_file=stop_file)
    except (KeyboardInterrupt, SystemExit):
        raise  # the sweep is being stopped: the run stays resumable from its checkpoint
    except RunBeingTrained as err:  # another process's run now: no error of the run's to keep
        return Outcome(job.name, "failed", error=str(err), pid=os.getpid())
    except Exception as err:  # a run's failure must not reach the sweep
        record_failure(run_dir, "".join(traceback.format_exception(err)))
        return Outcome(
            job.name,
            "failed",
            resumed=state == "resumable",
            error=f"{type(err).__name__}: {err}"[:2000],
            wall_time_s=time.perf_counter() - t0,
            pid=os.getpid(),
        )
    return Outcome(
        job.name,
        "done",
        resumed=state == "resumable",
        wall_time_s=time.perf_counter() - t0,
        pid=os.getpid(),
        verdict=_verdict(run_dir),
    )


def record_failure(run_dir: Path, text: str) -> None:
    """The run's ``error.txt``, which the sweep's tables read, written whole: a disk too full to
    take it loses the text (the run shows as incomplete), not the sweep."""
    with contextlib.suppress(OSError):
        run_dir.mkdir(parents=True, exist_ok=True)
        write_text(run_dir / ERROR_FILE, text)


def _verdict(run_dir: Path) -> str:
    """The run's verdict line; a run that trained is done even if its line cannot be made."""
    from sili_robots.verdict import verdict

    try:
        return verdict(run_dir)
    except Exception as err:
        return f"(no verdict: {type(err).__name__}: {err})"
