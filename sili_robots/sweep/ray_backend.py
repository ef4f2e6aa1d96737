"""Ray backend: the same jobs as Ray tasks, on an existing cluster or a local Ray instance.

Each run is one task with ``num_cpus=1`` and ``max_calls=1``, so Ray gives every run a fresh
worker process (libsumo: one simulation per process) and Ray's scheduler decides placement.
``max_retries`` re-runs a task whose worker died; the retry resumes from the run's checkpoint.
A stopped sweep (Ctrl-C, SIGTERM) asks each task to stop through a file in its run directory;
the task logs and checkpoints the interaction it is in, as the local backend's workers do.
On a multi-node cluster the sweep directory must be on a filesystem every node sees, and every
node needs this package installed. Ray is optional: ``pip install sili-robots[ray]``.
"""

from __future__ import annotations

import contextlib
import os
import signal
import socket
import threading
import time
from collections import deque
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

from sili_robots.errors import ConfigError, check_count
from sili_robots.runs import RUNNING_FILE, STOP_FILE
from sili_robots.stopping import STOP_SIGNALS, act_as
from sili_robots.sweep.backend import STOP_GRACE_S, Monitor
from sili_robots.sweep.worker import Job, Outcome, record_failure, run_job


def import_ray() -> Any:
    try:
        import ray
    except ImportError:
        raise ConfigError(
            "the ray backend needs Ray: pip install 'sili-robots[ray]' (or use --backend local)"
        ) from None
    return ray


class RayBackend:
    """Submit every job as a Ray task (at most ``workers`` in flight when given)."""

    def __init__(
        self, address: str | None = None, workers: int | None = None, retries: int = 0
    ) -> None:
        if address is not None and not isinstance(address, str):
            raise ConfigError(f"address must be a string or None, got {address!r}")
        self.address = address
        # as LocalBackend's: 1.5 workers would put two runs in flight, -1 retries Ray's forever
        self.workers = None if workers is None else check_count("workers", workers)
        self.retries = check_count("retries", retries, 0)

    def check_reachable(self) -> None:
        """ConfigError when nothing listens at ``address`` (see ``check_reachable``)."""
        if self.address:
            check_reachable(self.address)

    def _connect(self, ray: Any) -> bool:
        """Connect (or start a local instance); True when this call started Ray."""
        if ray.is_initialized():
            return False
        os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")  # no reporting home
        kwargs: dict[str, Any] = {"log_to_driver": False}
        if self.address:
            kwargs["address"] = self.address
        else:
            kwargs.update(  # "local": a new instance even where RAY_ADDRESS names a cluster
                address="local",
                num_cpus=self.workers or os.cpu_count() or 1,
                include_dashboard=False,
            )
        self.check_reachable()
        try:
            with _keeping_stop_handlers() as handlers:
                ray.init(**kwargs)
        except SystemExit as stop:
            if stop.code != signal.SIGTERM:
                raise
            # ray.init's own SIGTERM handler (exit 15) was in charge: stop as the command would
            with contextlib.suppress(Exception):
                ray.shutdown()
            act_as(signal.SIGTERM, handlers.get(signal.SIGTERM))
            raise SystemExit(128 + signal.SIGTERM) from None  # it was ignored: Ray is half up
        except ConnectionError as err:
            raise ConfigError(f"cannot connect to Ray at {self.address!r}: {err}") from None
        except ValueError as err:  # e.g. an address ray.init cannot read
            where = f"at {self.address!r}" if self.address else "(a local instance)"
            raise ConfigError(f"cannot start Ray {where}: {err}") from None
        return True

    def run(self, jobs: Sequence[Job], monitor: Monitor) -> list[Outcome]:
        ray = import_ray()
        started_here = self._connect(ray)
        remote = ray.remote(num_cpus=1, max_calls=1, max_retries=self.retries)(run_job)
        pending = deque(jobs)
        in_flight: dict[Any, Job] = {}
        not_started: set[str] = set()
        outcomes: list[Outcome] = []
        try:
            while pending or in_flight:
                while pending and (self.workers is None or len(in_flight) < self.workers):
                    job = pending.popleft()
                    in_flight[remote.remote(job)] = job
                    not_started.add(job.name)
                ready, _ = ray.wait(list(in_flight), num_returns=1, timeout=1.0)
                for ref in ready:
                    job = in_flight.pop(ref)
                    if job.name in not_started:
                        not_started.discard(job.name)
                        monitor.started(job)
                    outcome = self._result(ray, ref, job)
                    outcomes.append(outcome)
                    monitor.finished(outcome)
                for job in in_flight.values():
                    if job.name in not_started and (Path(job.run_dir) / RUNNING_FILE).exists():
                        not_started.discard(job.name)
                        monitor.started(job)
                monitor.tick()
        except BaseException:
            _stop(ray, in_flight, not_started)
            raise
        finally:
            if started_here:
                _wait_for_workers(ray, in_flight)
                ray.shutdown()
        return outcomes

    @staticmethod
    def _result(ray: Any, ref: Any, job: Job) -> Outcome:
        try:
            return ray.get(ref)
        except ray.exceptions.RayError as err:
            reason = str(err).strip().splitlines()[0] if str(err).strip() else type(err).__name__
            reason = f"{type(err).__name__}: {reason}"[:2000]
            record_failure(Path(job.run_dir), str(err) + "\n")
            (Path(job.run_dir) / RUNNING_FILE).unlink(missing_ok=True)
            return Outcome(job.name, "failed", error=reason)


def check_reachable(address: str, timeout: float = 5.0) -> None:
    """ConfigError when nothing listens at a Ray cluster's ``host:port`` (``ray://`` too), what
    listens there is not Ray, or ``auto`` finds no running cluster: ``ray.init`` would retry its
    connection forever, printing Ray's log lines, or fail once the sweep is written."""
    given = address
    if address == "auto":
        address = _running_cluster()
    hostport = address.split("://", 1)[-1]
    host, _, port = hostport.rpartition(":")
    if host.startswith("[") and host.endswith("]"):
        host = host[1:-1]  # [v6]:port
    elif ":" in host:  # a bare IPv6 address: where its port starts cannot be told
        return
    if not host or not port.isdigit():  # "auto", or an address ray.init names itself
        return
    try:
        socket.create_connection((host, int(port)), timeout=timeout).close()
    except OSError as err:
        problem = err.strerror or str(err)
    else:
        if _speaks_grpc(f"{host}:{port}" if ":" not in host else f"[{host}]:{port}", timeout):
            return
        problem = f"something listens there but does not answer as Ray does (gRPC) in {timeout:g} s"
    raise ConfigError(
        f"cannot connect to Ray at {address!r}"
        + (f" (--ray-address {given})" if given != address else "")
        + f": {problem}; is a Ray cluster's head (`ray start --head`) running there?"
    )


def _speaks_grpc(hostport: str, timeout: float) -> bool:
    """Whether ``hostport`` answers a gRPC handshake, as a Ray head's GCS and Ray Client do:
    ``ray.init`` would retry another service (a web server, say) for minutes, printing its
    log lines. With Ray's TLS on, or without grpc, the handshake is not tried."""
    if os.environ.get("RAY_USE_TLS", "0").lower() in ("1", "true"):
        return True
    try:
        import grpc
    except ImportError:
        return True
    # as Ray's own clients: straight to the cluster, whatever http_proxy or grpc_proxy say
    channel = grpc.insecure_channel(hostport, options=[("grpc.enable_http_proxy", 0)])
    try:
        grpc.channel_ready_future(channel).result(timeout=timeout)
    except grpc.FutureTimeoutError:
        return False
    finally:
        channel.close()
    return True


def _running_cluster() -> str:
    """The address ``auto`` stands for, as ``ray.init`` finds it (``RAY_ADDRESS``, else the
    cluster last started on this machine); ConfigError when there is none."""
    if os.environ.get("RAY_ADDRESS"):
        return os.environ["RAY_ADDRESS"]  # as given (ray:// too), probed as such
    try:
        from ray._private.services import canonicalize_bootstrap_address
    except ImportError:  # another Ray: ray.init alone tells
        return "auto"
    try:
        found = canonicalize_bootstrap_address("auto")
    except (ConnectionError, ValueError):
        found = None
    if found is None:
        raise ConfigError(
            "--ray-address auto finds no running Ray cluster (none started on this machine with "
            "`ray start --head`, and RAY_ADDRESS is not set): start one, give a cluster's "
            "host:port, or leave --ray-address out to start Ray here for this sweep"
        )
    return found


@contextlib.contextmanager
def _keeping_stop_handlers() -> Iterator[dict[int, Any]]:
    """``ray.init`` installs its own SIGTERM handler in the driver (``sys.exit(15)``);
    the command's own (``sili sweep``: stop like Ctrl-C, exit 128 + signal) is put back."""
    on_main = threading.current_thread() is threading.main_thread()
    signals = STOP_SIGNALS if on_main else ()
    handlers = {s: signal.getsignal(s) for s in signals}
    try:
        yield handlers
    finally:
        for sig, handler in handlers.items():
            if handler is not None:
                signal.signal(sig, handler)


def _stop(ray: Any, in_flight: dict[Any, Job], not_started: set[str]) -> None:
    """Stop the tasks as the local backend stops its workers: each run's stop file asks its
    training to stop once the interaction it is in is logged and checkpointed (Ray's own
    interrupt, ``ray.cancel`` without force, did not always reach a running task); a task
    still running after ``STOP_GRACE_S``, or at a second stop, is killed."""
    refs = list(in_flight)
    for ref, job in in_flight.items():
        (Path(job.run_dir) / STOP_FILE).touch()
        if job.name in not_started:  # still queued, most likely: it never starts
            ray.cancel(ref, force=False)
    not_ready = refs
    try:
        _, not_ready = ray.wait(refs, num_returns=len(refs), timeout=STOP_GRACE_S)
    finally:
        for ref in not_ready:
            ray.cancel(ref, force=True)
            (Path(in_flight[ref].run_dir) / RUNNING_FILE).unlink(missing_ok=True)
        for job in in_flight.values():
            (Path(job.run_dir) / STOP_FILE).unlink(missing_ok=True)


def _wait_for_workers(ray: Any, cancelled: dict[Any, Job]) -> None:
    """Give cancelled tasks a moment to stop before Ray is shut down."""
    if not cancelled:
        return
    deadline = time.monotonic() + 10
    while time.monotonic() < deadline:
        _, not_ready = ray.wait(list(cancelled), num_returns=len(cancelled), timeout=0.5)
        if not not_ready:
            return
