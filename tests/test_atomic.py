"""Files replaced whole: old or new, never half, and concurrent writers never collide."""

from __future__ import annotations

import os
import threading

import pytest

from sili_robots.atomic import replacing, write_text


def test_a_failed_write_leaves_the_old_file_and_no_temporary(tmp_path):
    path = tmp_path / "table.csv"
    write_text(path, "old")
    with pytest.raises(RuntimeError), replacing(path) as tmp:
        tmp.write_text("half of the new")
        raise RuntimeError("killed")
    assert path.read_text() == "old" and sorted(tmp_path.iterdir()) == [path]


def test_shared_writers_of_one_file_do_not_collide(tmp_path):
    """Two processes writing a sweep's tables at once (`sili plot` during `sili claims`)."""
    path, errors = tmp_path / "results.csv", []

    def writer(text: str) -> None:
        try:
            for _ in range(200):
                write_text(path, text * 1000, shared=True)
        except OSError as err:
            errors.append(err)

    threads = [threading.Thread(target=writer, args=(t,)) for t in "ab"]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not errors
    assert path.read_text() in ("a" * 1000, "b" * 1000)
    assert sorted(tmp_path.iterdir()) == [path]


def test_the_new_file_is_on_disk_before_it_replaces_the_old(tmp_path, monkeypatch):
    """A crash of the machine after the rename must not leave an empty checkpoint or table."""
    events: list[str] = []
    fsync, replace = os.fsync, os.replace

    def synced(fd: int) -> None:
        events.append(f"fsync {os.readlink(f'/proc/self/fd/{fd}')}")
        fsync(fd)

    def replaced(src, dst) -> None:
        events.append(f"replace {src}")
        replace(src, dst)

    monkeypatch.setattr(os, "fsync", synced)
    monkeypatch.setattr(os, "replace", replaced)
    write_text(tmp_path / "checkpoint.pt", "new")
    tmp = tmp_path / "checkpoint.pt.tmp"
    assert events == [f"fsync {tmp}", f"replace {tmp}", f"fsync {tmp_path}"]


def test_training_syncs_its_history_before_each_checkpoint(tmp_path, monkeypatch):
    from fast_settings import FAST_AGENT

    from sili_robots import runs, training
    from sili_robots.build import make_run_config

    events: list[str] = []
    sync, save = runs.MetricsWriter.sync, training.save_checkpoint

    def synced(self) -> None:
        events.append(f"metrics {len(self.path.read_text().splitlines()) - 1}")
        sync(self)

    def saved(run_dir, state) -> None:
        events.append(f"checkpoint {state['interaction']}")
        save(run_dir, state)

    monkeypatch.setattr(runs.MetricsWriter, "sync", synced)
    monkeypatch.setattr(training, "save_checkpoint", saved)
    cfg = make_run_config("circle-3", "sac", 0, 4, settings=FAST_AGENT, checkpoint_every=2)
    training.train(cfg, tmp_path / "run", progress=False)
    assert events == ["metrics 2", "checkpoint 2", "metrics 4", "checkpoint 4"]


def test_a_directory_where_the_file_goes_is_named_before_anything_is_written(tmp_path):
    from sili_robots.errors import ConfigError

    (tmp_path / "results.csv").mkdir()
    with pytest.raises(ConfigError, match=r"results.csv is a directory, where a file is written"):
        write_text(tmp_path / "results.csv", "table")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["results.csv"]
