"""The float32 kernel library is chosen by a timing on the machine at hand, cached, and recorded
with each run."""

from __future__ import annotations

import json
import tempfile

import pytest

from sili_robots.agent import matmul
from sili_robots.agent.config import AgentConfig
from sili_robots.errors import ConfigError


@pytest.fixture
def cache(tmp_path, monkeypatch):
    monkeypatch.setenv("SILI_ROBOTS_CACHE", str(tmp_path))
    return tmp_path / "kernels.json"


@pytest.fixture
def float32_timed(monkeypatch):
    """The precision's timing (a real one takes seconds: bfloat16 runs slowly without bfloat16
    units) as a machine that keeps float32 would measure it."""
    monkeypatch.setattr(matmul, "time_precisions", lambda _m: {"float32": 1e-2, "bfloat16": 2e-2})


def test_the_faster_library_is_chosen_and_the_choice_cached(cache, monkeypatch, float32_timed):
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


@pytest.mark.parametrize("damaged", ["[1, 2]", '{"KEY": [1]}', '{"KEY": "aten"}'])
def test_a_damaged_cache_is_timed_again_and_rewritten(cache, monkeypatch, damaged):
    """Valid JSON of another shape (a file written by hand, say) is as good as none."""
    monkeypatch.setattr(matmul, "time_matmuls", lambda: {"onednn": 2e-3, "aten": 1e-3})
    cache.write_text(damaged.replace("KEY", matmul.machine_key()))
    assert matmul.default_matmul() == "aten"
    assert json.loads(cache.read_text())[matmul.machine_key()]["matmul"] == "aten"


@pytest.mark.parametrize("aten", ["1e-3", 0, -1e-3])
def test_damaged_timings_in_the_cache_give_no_note(cache, aten, float32_timed):
    entry = {"matmul": "aten", "seconds": {"aten": aten, "onednn": 2e-3}}
    cache.write_text(json.dumps({matmul.machine_key(): entry}))
    assert matmul.default_matmul() == "aten"  # the choice stands; its timings are not read
    assert matmul.slow_kernels("onednn", "float32") == []


@pytest.mark.parametrize(("onednn", "chosen"), [(0.99e-3, "aten"), (0.9e-3, "onednn")])
def test_onednn_is_chosen_only_where_clearly_faster(cache, monkeypatch, onednn, chosen):
    """A near tie takes ATen, so a timing under load does not flip a fresh cache's choice
    (and with it every run's numbers)."""
    if not matmul.onednn_available():
        pytest.skip("this PyTorch has no oneDNN linear op: aten is the only library")
    monkeypatch.setattr(matmul, "time_matmuls", lambda: {"onednn": onednn, "aten": 1e-3})
    assert matmul.default_matmul() == chosen


def test_a_real_timing_measures_both_libraries(cache):
    times = matmul.time_matmuls(width=64, batch=32, rounds=1)
    assert set(times) == set(matmul.MATMULS) and all(0 < t < 1 for t in times.values())
    assert matmul.default_matmul() in matmul.MATMULS
    assert "1 thread" in matmul.machine_key() and "torch" in matmul.machine_key()


def test_bfloat16_is_chosen_only_where_it_clearly_pays_and_the_choice_is_cached(cache, monkeypatch):
    monkeypatch.setattr(matmul, "default_matmul", lambda: "aten")
    timed = []

    def times(speedup):
        def fake(matmul_name):
            timed.append(matmul_name)
            return {"float32": 1e-2, "bfloat16": 1e-2 / speedup}

        return fake

    monkeypatch.setattr(matmul, "time_precisions", times(1.1))  # faster, but not by enough
    assert matmul.default_precision() == "float32" and timed == ["aten"]
    cache.unlink()
    monkeypatch.setattr(matmul, "time_precisions", times(1.5))
    assert matmul.default_precision() == "bfloat16"
    assert matmul.default_precision() == "bfloat16" and len(timed) == 2  # measured once
    entry = json.loads(cache.read_text())[matmul.machine_key()]
    assert entry["precision"] == "bfloat16" and entry["precision_seconds"]["float32"] == 1e-2
    assert AgentConfig().sac.precision == "bfloat16"  # what a new run records in config.json


def test_a_real_timing_measures_a_sac_update_in_both_precisions(cache):
    times = matmul.time_precisions("aten", updates=2, rounds=1)
    # seconds per update; bfloat16 without its units: about 0.25 s idle, over 1 s on busy cores
    assert set(times) == set(matmul.PRECISIONS) and all(0 < t < 10 for t in times.values())
    assert matmul.default_precision() in matmul.PRECISIONS
    assert json.loads(cache.read_text())[matmul.machine_key()]["precision"] in matmul.PRECISIONS


def test_a_capped_instruction_set_is_timed_apart_from_the_full_one(cache, monkeypatch):
    for cap in matmul.ISA_CAPS:
        monkeypatch.delenv(cap, raising=False)
    full = matmul.machine_key()
    monkeypatch.setenv("ONEDNN_MAX_CPU_ISA", "AVX2")
    assert matmul.machine_key() != full and "ONEDNN_MAX_CPU_ISA=AVX2" in matmul.machine_key()
    monkeypatch.setattr(matmul, "time_matmuls", lambda: {"onednn": 2e-3, "aten": 1e-3})
    assert matmul.default_matmul() == "aten"
    monkeypatch.delenv("ONEDNN_MAX_CPU_ISA")
    monkeypatch.setattr(matmul, "time_matmuls", lambda: {"onednn": 1e-3, "aten": 2e-3})
    assert matmul.default_matmul() == "onednn"  # not the capped run's cached choice


def test_two_cpu_generations_under_one_name_are_timed_apart():
    """A virtual machine names Zen 4 and Zen 5 both "AMD EPYC": the family and model tell them
    apart, so one's cached kernel choice is not taken on the other."""
    zen4 = (
        "processor\t: 0\ncpu family\t: 25\nmodel\t\t: 17\nmodel name\t: AMD EPYC\nstepping\t: 1\n"
    )
    flags = "flags\t\t: fpu avx2 avx512f sse\n"
    zen5 = zen4.replace(": 25", ": 26").replace(": 17", ": 2")
    second = "\n\nprocessor\t: 1\nmodel name\t: other\n"
    assert matmul.cpu_of(zen4 + flags + second) == (
        "AMD EPYC (cpu family 25, model 17, stepping 1)",
        "avx2 avx512f",
    )
    assert matmul.cpu_of(zen5 + flags)[0] == "AMD EPYC (cpu family 26, model 2, stepping 1)"
    assert matmul.cpu_of("model name\t: Apple M2\n") == ("Apple M2", "")


def test_the_cache_is_never_a_tilde_folder_in_the_current_directory(monkeypatch, tmp_path):
    """Without $HOME and a user entry (some containers), expanduser leaves "~" as it is: the
    cache went to ./~/.cache; now to the temporary directory."""
    import pwd

    from sili_robots.cache import cache_dir

    for name in ("SILI_ROBOTS_CACHE", "XDG_CACHE_HOME", "HOME"):
        monkeypatch.delenv(name, raising=False)
    monkeypatch.setattr(pwd, "getpwuid", lambda uid: (_ for _ in ()).throw(KeyError(uid)))
    monkeypatch.setenv("TMPDIR", str(tmp_path))
    monkeypatch.setattr(tempfile, "tempdir", None)  # read TMPDIR again
    assert cache_dir() == tmp_path / "sili-robots-cache"
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    assert cache_dir() == tmp_path / "home" / ".cache" / "sili-robots"
    monkeypatch.setenv("SILI_ROBOTS_CACHE", "~/c")  # a quoted ~ too
    assert cache_dir() == tmp_path / "home" / "c"
    monkeypatch.setenv("SILI_ROBOTS_CACHE", "~nosuchuser-sili/c")
    with pytest.raises(ConfigError, match=r"SILI_ROBOTS_CACHE is '~nosuchuser-sili/c', whose '~' "):
        cache_dir()


def test_caching_the_precision_keeps_the_cached_library(cache, monkeypatch):
    """Both choices live in one entry per machine: caching one must not erase the other (the
    library would be timed again at every start, and a fresh timing may choose another)."""
    timed = []

    def fake_matmuls():
        timed.append(1)
        return {"onednn": 1e-3, "aten": 2e-3}

    monkeypatch.setattr(matmul, "onednn_available", lambda: True)
    monkeypatch.setattr(matmul, "time_matmuls", fake_matmuls)
    monkeypatch.setattr(matmul, "time_precisions", lambda m: {"float32": 1e-3, "bfloat16": 2e-3})
    assert matmul.default_precision() == "float32"
    assert matmul.default_matmul() == "onednn"
    assert len(timed) == 1  # measured once, then read from the cache
    (entry,) = json.loads(cache.read_text()).values()
    assert entry["matmul"] == "onednn" and entry["precision"] == "float32"


def test_a_onednn_layer_under_bfloat16_autocast_computes_in_bfloat16():
    """Autocast sends bfloat16 products to oneDNN itself: a layer given ``onednn`` takes
    PyTorch's path there, not the float32 oneDNN op (which would undo the bfloat16)."""
    import torch

    if not matmul.onednn_available():
        pytest.skip("this PyTorch has no oneDNN linear op: aten is the only library")
    layer = matmul.Linear(32, 32, "onednn")
    with torch.autocast("cpu", dtype=torch.bfloat16):
        assert layer(torch.randn(8, 32)).dtype == torch.bfloat16


def test_xdg_cache_home_gets_a_sili_robots_folder_of_its_own(monkeypatch, tmp_path):
    """With $XDG_CACHE_HOME set, the cache is its sili-robots folder, not the shared root;
    $SILI_ROBOTS_CACHE wins over it."""
    from sili_robots.cache import cache_dir

    monkeypatch.delenv("SILI_ROBOTS_CACHE", raising=False)
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert cache_dir() == tmp_path / "xdg" / "sili-robots"
    monkeypatch.setenv("XDG_CACHE_HOME", "~/xdg")  # a quoted ~ is expanded here too
    assert cache_dir() == tmp_path / "home" / "xdg" / "sili-robots"
    monkeypatch.setenv("SILI_ROBOTS_CACHE", str(tmp_path / "own"))
    assert cache_dir() == tmp_path / "own"


def test_an_empty_cache_variable_is_as_if_unset_not_the_current_directory(monkeypatch, tmp_path):
    """SILI_ROBOTS_CACHE= (set but empty) falls back to the default cache, never '.'."""
    from sili_robots.cache import cache_dir

    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    monkeypatch.delenv("XDG_CACHE_HOME", raising=False)
    monkeypatch.setenv("SILI_ROBOTS_CACHE", "")
    assert cache_dir() == tmp_path / "home" / ".cache" / "sili-robots"
