"""The memory cap of a training process: an allocation past what the machine can give fails at
once, with the CLI's one-line message, instead of being killed by Linux."""

import resource

import numpy as np
import pytest
from fast_settings import FAST_ARGS

from sili_robots import memory
from sili_robots.cli import main

pytestmark = pytest.mark.skipif(memory.available_memory() is None, reason="needs /proc/meminfo")
MIB = 2**20


def test_the_cap_refuses_more_than_is_available_and_is_lifted_after(monkeypatch):
    before = resource.getrlimit(resource.RLIMIT_DATA)
    monkeypatch.setattr(memory, "available_memory", lambda: 200 * MIB)
    with memory.capped_at_available():
        assert resource.getrlimit(resource.RLIMIT_DATA)[0] != resource.RLIM_INFINITY
        with pytest.raises(MemoryError):
            np.empty(memory.HEADROOM + 400 * MIB, np.uint8)  # more than "available"
        np.ones(20 * MIB, np.uint8)  # what fits still does
    assert resource.getrlimit(resource.RLIMIT_DATA) == before


def test_overlapping_caps_lift_only_when_the_last_ends(monkeypatch):
    """Trainings in two threads: the first to end must not lift the other's cap, nor the last
    leave the first's cap behind."""
    before = resource.getrlimit(resource.RLIMIT_DATA)
    monkeypatch.setattr(memory, "available_memory", lambda: 200 * MIB)
    first, second = memory.capped_at_available(), memory.capped_at_available()
    first.__enter__()
    capped = resource.getrlimit(resource.RLIMIT_DATA)
    second.__enter__()
    first.__exit__(None, None, None)
    assert resource.getrlimit(resource.RLIMIT_DATA) == capped
    second.__exit__(None, None, None)
    assert resource.getrlimit(resource.RLIMIT_DATA) == before


def test_training_past_the_memory_left_exits_1_with_one_line(tmp_path, monkeypatch, capsys):
    before = resource.getrlimit(resource.RLIMIT_DATA)
    monkeypatch.setattr(memory, "available_memory", lambda: 100 * MIB)
    # the latent model's batch: 100,000 pairs x 50 steps x 32 units, 640 MB a layer
    args = ["train", "--task", "circle-3", "--interactions", "3", *FAST_ARGS, "--no-progress"]
    assert main([*args, "--set", "model.batch=100000", "--out", str(tmp_path / "run")]) == 1
    err = capsys.readouterr().err
    assert err.startswith("sili train: error: out of memory (") and len(err.splitlines()) == 1
    assert resource.getrlimit(resource.RLIMIT_DATA) == before


def test_overwrite_keeps_the_run_when_the_new_agent_does_not_fit(tmp_path, monkeypatch, capsys):
    """The agent is built before --overwrite removes the run there, not after."""
    run = tmp_path / "run"
    args = ["train", "--task", "circle-3", "--interactions", "2", *FAST_ARGS, "--no-progress"]
    assert main([*args, "--out", str(run)]) == 0
    before = {p.name: p.read_bytes() for p in run.iterdir() if p.is_file()}
    monkeypatch.setattr(memory, "available_memory", lambda: 100 * MIB)
    huge = ["--set", "hidden=20000", "--overwrite"]  # a 1.6 GB layer
    assert main([*args, *huge, "--out", str(run)]) == 1
    assert "sili train: error: out of memory (" in capsys.readouterr().err
    assert {p.name: p.read_bytes() for p in run.iterdir() if p.is_file()} == before


def test_a_sweep_overwrite_keeps_its_runs_when_a_new_agent_does_not_fit(tmp_path, monkeypatch):
    out = tmp_path / "sweep"
    args = ["sweep", "--tasks", "circle-3", "--methods", "sac", "--seeds", "0-1", *FAST_ARGS]
    args += ["--interactions", "2", "--no-progress", "--workers", "1", "--out", str(out)]
    assert main(args) == 0
    before = {p: p.read_bytes() for p in out.rglob("*") if p.is_file() and "tb" not in p.parts}
    monkeypatch.setattr(memory, "available_memory", lambda: 100 * MIB)
    assert main([*args, "--set", "hidden=20000", "--overwrite"]) == 1
    assert {p: p.read_bytes() for p in before} == before and all(p.exists() for p in before)


def test_a_lower_limit_already_set_stays(monkeypatch):
    """``ulimit -d`` below what the machine has free is the user's: the cap never raises it."""
    before = resource.getrlimit(resource.RLIMIT_DATA)
    vm_data = memory._kib("/proc/self/status", "VmData")["VmData"]
    lower = vm_data + 300 * MIB
    resource.setrlimit(resource.RLIMIT_DATA, (lower, before[1]))
    try:
        monkeypatch.setattr(memory, "available_memory", lambda: 10 * 2**30)
        with memory.capped_at_available():
            assert resource.getrlimit(resource.RLIMIT_DATA)[0] == lower
        assert resource.getrlimit(resource.RLIMIT_DATA)[0] == lower
    finally:
        resource.setrlimit(resource.RLIMIT_DATA, before)


def test_a_containers_memory_limit_bounds_what_is_available(monkeypatch, tmp_path):
    limit, usage = tmp_path / "memory.max", tmp_path / "memory.current"
    limit.write_text(f"{2**30}\n")
    usage.write_text(f"{600 * MIB}\n")
    monkeypatch.setattr(memory, "CGROUP_FILES", ((str(limit), str(usage)),))
    assert memory.available_memory() <= 424 * MIB
    limit.write_text("max\n")  # no limit: the machine's memory
    assert memory.available_memory() > 424 * MIB


def test_a_container_over_its_limit_has_nothing_left_not_less_than_nothing(monkeypatch, tmp_path):
    """Usage above the limit (cgroup v1 counts the page cache): 0 available, never a negative
    amount, which would cap the process below what it already uses."""
    limit, usage = tmp_path / "memory.max", tmp_path / "memory.current"
    limit.write_text(f"{2**30}\n")
    usage.write_text(f"{2 * 2**30}\n")
    monkeypatch.setattr(memory, "CGROUP_FILES", ((str(limit), str(usage)),))
    if memory.available_memory() is None:
        pytest.skip("needs /proc/meminfo")
    assert memory.available_memory() == 0


def test_free_swap_counts_as_memory_the_machine_can_give(monkeypatch, tmp_path):
    """Without it, a training that fits in swap was refused as "out of memory"."""
    real = memory._kib
    meminfo = tmp_path / "meminfo"  # read by the real parser: the fields it asks for count
    meminfo.write_text(
        f"MemTotal: {4096 * 1024} kB\nMemAvailable: {300 * 1024} kB\nSwapFree: {700 * 1024} kB\n"
    )

    def kib(path, *fields):
        return real(str(meminfo) if path == "/proc/meminfo" else path, *fields)

    monkeypatch.setattr(memory, "_kib", kib)
    monkeypatch.setattr(memory, "CGROUP_FILES", ((str(tmp_path / "no"), str(tmp_path / "no")),))
    assert memory.available_memory() == 1000 * MIB
    limit, usage = tmp_path / "memory.max", tmp_path / "memory.current"
    limit.write_text(f"{2**30}\n")  # a container's 1 GiB, 100 MiB of it used
    usage.write_text(f"{100 * MIB}\n")
    monkeypatch.setattr(memory, "CGROUP_FILES", ((str(limit), str(usage)),))
    assert memory.available_memory() == pytest.approx(924 * MIB)


def test_memory_reserved_but_never_touched_fits_under_the_cap_when_nothing_is_free(monkeypatch):
    """Without the headroom, a replay buffer's doubled (untouched) half failed as out of memory."""
    before = resource.getrlimit(resource.RLIMIT_DATA)
    monkeypatch.setattr(memory, "available_memory", lambda: 0)
    with memory.capped_at_available():
        reserved = np.empty(256 * MIB, np.uint8)  # counted, never touched
        assert reserved.nbytes == 256 * MIB
        del reserved
    assert resource.getrlimit(resource.RLIMIT_DATA) == before
