"""Sweeps: many training runs (tasks x methods x seeds x b x controllers) on a local process
pool or Ray, one tidy results table per sweep, resumable run by run."""

from sili_robots.sweep.backend import Backend, Monitor, NullMonitor
from sili_robots.sweep.local import LocalBackend
from sili_robots.sweep.ray_backend import RayBackend
from sili_robots.sweep.results import results_table, runs_table, write_tables
from sili_robots.sweep.runner import SweepReport, plan, run_sweep
from sili_robots.sweep.spec import (
    PlannedRun,
    SweepSpec,
    expand,
    parse_betas,
    parse_list,
    parse_seeds,
    run_name,
)

__all__ = [
    "Backend",
    "LocalBackend",
    "Monitor",
    "NullMonitor",
    "PlannedRun",
    "RayBackend",
    "SweepReport",
    "SweepSpec",
    "expand",
    "parse_betas",
    "parse_list",
    "parse_seeds",
    "plan",
    "results_table",
    "run_name",
    "run_sweep",
    "runs_table",
    "write_tables",
]
