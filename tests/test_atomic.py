"""Files replaced whole: old or new, never half, and concurrent writers never collide."""

from __future__ import annotations

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
