"""The memory cap of a training process: an allocation past what the machine can give fails at
once, with the CLI's one-line message, instead of being killed by Linux."""

import resource

import numpy as np
import pytest
from fast_settings import FAST_ARGS

from sili_robots import memory
from sili_robots.cli import main

pytestmark = pytest.mark.skipif(memory.available_memory() is None, reason="needs /proc/meminfo")


def test_the_cap_refuses_more_than_is_available_and_is_lifted_after(monkeypatch):
    before = resource.getrlimit(resource.RLIMIT_DATA)
    monkeypatch.setattr(memory, "available_memory", lambda: 200 * 2**20)
    with memory.capped_at_available():
        soft, _ = resource.getrlimit(resource.RLIMIT_DATA)
        assert soft != resource.RLIM_INFINITY
        with pytest.raises(MemoryError):
            np.ones(400 * 2**20, np.uint8)  # twice what is "available"
        np.ones(20 * 2**20, np.uint8)  # what fits still does
    assert resource.getrlimit(resource.RLIMIT_DATA) == before


def test_training_past_the_memory_left_exits_1_with_one_line(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(memory, "available_memory", lambda: 100 * 2**20)
    # the latent model's batch: 20,000 pairs x 50 steps x 32 units, 128 MB a layer
    args = ["train", "--task", "circle-3", "--interactions", "3", *FAST_ARGS, "--no-progress"]
    assert main([*args, "--set", "model.batch=20000", "--out", str(tmp_path / "run")]) == 1
    err = capsys.readouterr().err
    assert err.startswith("sili train: error: out of memory (") and len(err.splitlines()) == 1
