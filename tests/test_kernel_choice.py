"""The float32 kernel library is chosen by a timing on the machine at hand, cached, and recorded
with each run."""

from __future__ import annotations

import json

import pytest

from sili_robots.agent import matmul
from sili_robots.agent.config import AgentConfig


@pytest.fixture
def cache(tmp_path, monkeypatch):
    monkeypatch.setenv("SILI_ROBOTS_CACHE", str(tmp_path))
    return tmp_path / "kernels.json"


def test_the_faster_library_is_chosen_and_the_choice_cached(cache, monkeypatch):
    if not matmul.onednn_available():
        pytest.skip("this PyTorch has no oneDNN linear op: aten is the only library")
    timed = []

    def fake_times():
        timed.append(1)
        return {"onednn": 2e-3, "aten": 1e-3}

    monkeypatch.setattr(matmul, "time_matmuls", fake_times)
    assert matmul.default_matmul() == "aten"  # the faster one, though oneDNN exists
    assert matmul.default_matmul() == "aten" and len(timed) == 1  # measured once
    entry = json.loads(cache.read_text())[matmul.machine_key()]
    assert entry == {"matmul": "aten", "seconds": {"onednn": 2e-3, "aten": 1e-3}}
    assert AgentConfig().matmul == "aten"  # what a new run records in config.json


def test_a_real_timing_measures_both_libraries(cache):
    times = matmul.time_matmuls(width=64, batch=32, rounds=1)
    assert set(times) == set(matmul.MATMULS) and all(0 < t < 1 for t in times.values())
    assert matmul.default_matmul() in matmul.MATMULS
    assert "1 thread" in matmul.machine_key() and "torch" in matmul.machine_key()
