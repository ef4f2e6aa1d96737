"""Files replaced whole: old or new, never half, and concurrent writers never collide."""

from __future__ import annotations

import os
import threading

import matplotlib.pyplot as plt
import pytest
from disk_helpers import file_size_limit

from sili_robots.atomic import replacing, write_text
from sili_robots.commands.claims import END, START, write_block
from sili_robots.metrics import MetricsWriter
from sili_robots.plotting import save_figure


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

    from sili_robots import metrics, training
    from sili_robots.build import make_run_config

    events: list[str] = []
    sync, save = metrics.MetricsWriter.sync, training.save_checkpoint

    def synced(self) -> None:
        events.append(f"metrics {len(self.path.read_text().splitlines()) - 1}")
        sync(self)

    def saved(run_dir, state) -> None:
        events.append(f"checkpoint {state['interaction']}")
        save(run_dir, state)

    monkeypatch.setattr(metrics.MetricsWriter, "sync", synced)
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


def test_a_write_the_disk_refuses_names_the_file_and_keeps_the_old_one(tmp_path):
    """A full disk's failed write names no file; the error does (the CLI prints it)."""
    path = tmp_path / "summary.json"
    write_text(path, "old")
    with pytest.raises(OSError) as refused, file_size_limit(1000):
        write_text(path, "new" * 1000)
    assert (refused.value.filename, refused.value.strerror) == (str(path), "File too large")
    assert path.read_text() == "old" and sorted(tmp_path.iterdir()) == [path]


def test_figures_and_the_claims_block_keep_the_old_file_when_the_disk_refuses(tmp_path):
    """`sili plot` and `sili claims --write` replace their files whole: a full disk leaves the
    figure drawn before, and the README as it was (it truncated them)."""
    fig, ax = plt.subplots()
    (old,) = save_figure(fig, tmp_path / "curve", formats=("png",))
    drawn = old.read_bytes()
    ax.plot(range(1000), range(1000), marker="o")
    with pytest.raises(OSError) as refused, file_size_limit(len(drawn) + 100):
        save_figure(fig, tmp_path / "curve", formats=("png",))
    plt.close(fig)
    assert refused.value.filename == str(old) and old.read_bytes() == drawn
    readme = tmp_path / "README.md"
    readme.write_text(f"intro\n{START}\nold table\n{END}\nrest\n")
    kept = readme.read_bytes()
    with pytest.raises(OSError), file_size_limit(len(kept) + 10):
        write_block(readme, "a much longer table\n" * 10)
    assert readme.read_bytes() == kept
    write_block(readme, "new table\n")
    assert readme.read_text() == f"intro\n{START}\nnew table\n{END}\nrest\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["README.md", "curve.png"]


def test_a_link_keeps_pointing_at_the_file_replaced_and_the_file_its_permissions(tmp_path):
    real, link = tmp_path / "real.md", tmp_path / "README.md"
    real.write_text("old")
    real.chmod(0o664)
    link.symlink_to(real)
    write_text(link, "new")
    assert link.is_symlink() and real.read_text() == "new"
    assert real.stat().st_mode & 0o777 == 0o664


def test_a_link_to_itself_is_replaced_as_a_file(tmp_path):
    loop = tmp_path / "loop"
    loop.symlink_to(loop)
    write_text(loop, "new")
    assert not loop.is_symlink() and loop.read_text() == "new"


def test_a_refused_temporary_is_named_as_the_file_it_stands_for(tmp_path):
    """A folder that cannot take the temporary (read-only, out of inodes) names the file."""
    target = tmp_path / "missing" / "summary.json"
    with pytest.raises(OSError) as refused:
        write_text(target, "x")
    assert refused.value.filename == str(target)


def test_a_metrics_row_the_disk_refuses_names_the_file(tmp_path):
    writer = MetricsWriter(tmp_path, columns=("interaction", "note"))
    writer.write({"interaction": 0, "note": "x"})
    size = (tmp_path / "metrics.csv").stat().st_size
    with pytest.raises(OSError) as refused, file_size_limit(size + 10):
        writer.write({"interaction": 1, "note": "y" * 100})
    assert refused.value.filename == str(tmp_path / "metrics.csv")
    writer.close()
