"""Float32 linear layers on oneDNN, the other CPU matrix-product library inside PyTorch.

Why: PyTorch sends float32 matrix products to its BLAS (MKL in the x86 wheels), and on some
CPUs that runs them well below what the hardware does. Measured on an AMD EPYC (Zen 5, one
thread): a 256-wide layer of SAC's update in 0.73 ms through oneDNN against 1.28 ms through the
BLAS (benchmarks/RESULTS.md, "SAC gradient updates per second"; ``benchmarks/bench_sac_speed.py
--matmul-only`` times the products alone). SAC's update is mostly such products, so the kernel
library decides much of its speed.

PyTorch reaches oneDNN's float32 matmul only through ``torch.ops.mkldnn._linear_pointwise``,
the op its own compiler emits for CPU linear layers. That op has no autograd formula, so the
functions here supply the backward: two more oneDNN products (gradients of the input and of
the weight) and a sum for the bias. The arithmetic is float32 as before, in another summation
order: results agree with ``aten`` to rounding, not bit for bit, so ``matmul`` is an agent
setting saved with each run (a resumed run keeps the kernels it was trained with).

``matmul="aten"`` is PyTorch's default path. Under autocast (``precision="bfloat16"``) layers
always take it: autocast already sends bfloat16 products to oneDNN.

Which library is faster depends on the CPU (oneDNN 2x on one AMD EPYC, slower than MKL on
another), so the default is chosen by measurement: ``default_matmul`` times a SAC-sized layer's
forward and backward on both (at one thread, as training runs), once per machine and torch
version, and caches the choice (``kernels.json`` in the package's cache directory). The
precision of SAC's products is chosen the same way (``default_precision``): bfloat16 only where
a whole SAC update runs at least ``BF16_SPEEDUP`` times as fast (CPUs with bfloat16 units; on
AVX2 alone it is ~10x slower). A run records both choices in its config, so it resumes on the
kernels it was trained with.
"""

from __future__ import annotations

import json
import math
import os
import platform
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import torch
import torch.nn.functional as F
from torch import nn

from sili_robots.atomic import write_text
from sili_robots.cache import cache_dir
from sili_robots.errors import is_number

MATMULS = ("onednn", "aten")
#: oneDNN is chosen over ATen (torch's own path) only when clearly faster: on a near tie a
#: timing taken while the machine is busy could choose either, and the choice changes the
#: numbers of every run a fresh cache trains
ONEDNN_SPEEDUP = 1.05
PRECISIONS = ("float32", "bfloat16")
#: bfloat16 changes the numerics, so it is chosen only where it clearly pays (a SAC update:
#: 1.4x oneDNN float32 on Zen 5 with AVX512-BF16, 0.1x on AVX2 alone; benchmarks/RESULTS.md)
BF16_SPEEDUP = 1.25
#: layers narrower than this stay on ``aten``: for a [B, 256] x [256, 1] product the library
#: call costs more than the arithmetic (measured: 5 us through aten, 19 us through oneDNN)
MIN_WIDTH = 16


def onednn_available() -> bool:
    """Whether this PyTorch build has oneDNN's linear op (the x86 and aarch64 wheels do)."""
    ops = torch.ops.mkldnn
    return torch.backends.mkldnn.is_available() and hasattr(ops, "_linear_pointwise")


#: environment variables that cap the instruction set torch's kernels use (set to emulate an
#: older processor), so a timing made under one is not reused without it
ISA_CAPS = (
    "ATEN_CPU_CAPABILITY",
    "ONEDNN_MAX_CPU_ISA",
    "DNNL_MAX_CPU_ISA",
    "MKL_ENABLE_INSTRUCTIONS",
)


def isa_caps() -> dict[str, str]:
    """The instruction-set caps set in this process (``ISA_CAPS`` that have a value)."""
    return {v: os.environ[v] for v in ISA_CAPS if os.environ.get(v)}


def cpu_of(cpuinfo: str) -> tuple[str, str]:
    """(model, vector flags) of the first processor in ``/proc/cpuinfo``'s text. The model
    names its family, model and stepping: a virtual machine may name two generations alike
    ("AMD EPYC"), and a kernel choice of one does not hold for the other."""
    cpu: dict[str, str] = {}
    for line in cpuinfo.split("\n\n")[0].splitlines():  # every core reads alike
        key, _, value = line.partition(":")
        cpu[key.strip()] = value.strip()
    model = cpu.get("model name") or platform.processor()
    generation = ", ".join(f"{k} {cpu[k]}" for k in ("cpu family", "model", "stepping") if k in cpu)
    flags = sorted(f for f in cpu.get("flags", "").split() if f.startswith(("avx", "amx")))
    return model + (f" ({generation})" if generation else ""), " ".join(flags)


def machine_key(threads: int = 1) -> str:
    """What a kernel timing depends on: CPU model and flags, any instruction-set cap, torch
    version and thread count (timings run on one thread, as training does by default)."""
    try:
        model, flags = cpu_of(Path("/proc/cpuinfo").read_text())
    except OSError:
        model, flags = platform.processor(), ""
    caps = "".join(f" | {v}={value}" for v, value in isa_caps().items())
    count = f"{threads} thread" + ("s" if threads > 1 else "")
    return f"{model} | {flags}{caps} | torch {torch.__version__} | {count}"


def time_matmuls(width: int = 256, batch: int = 256, rounds: int = 4) -> dict[str, float]:
    """Seconds per forward and backward of a [batch, width] x [width, width] layer, the best
    of ``rounds`` interleaved rounds per library (interleaved, so a busy neighbour slows both)."""
    x = torch.randn(batch, width, requires_grad=True)
    layers = {m: Linear(width, width, m) for m in MATMULS}
    best = dict.fromkeys(MATMULS, float("inf"))
    for _ in range(rounds):
        for m, layer in layers.items():
            start = time.perf_counter()
            for _ in range(20):
                layer(x).sum().backward()
            best[m] = min(best[m], (time.perf_counter() - start) / 20)
    return best


def time_precisions(matmul: str, updates: int = 10, rounds: int = 3) -> dict[str, float]:
    """Seconds per SAC update (2 x 256 networks, batch 256, as the agent's) in float32 on
    ``matmul`` and with its products in bfloat16: the best of ``rounds`` interleaved rounds.
    A whole update, not one layer: autocast's casts and the float32 optimizer are part of it."""
    from sili_robots.agent.sac import SAC

    g = torch.Generator().manual_seed(0)
    x, x2 = torch.randn(2, 256, 32, generator=g)
    a, r = torch.rand(256, 2, generator=g) * 2 - 1, torch.randn(256, generator=g)
    sacs = {p: SAC(32, 2, hidden=256, precision=p, matmul=matmul) for p in PRECISIONS}
    best = dict.fromkeys(PRECISIONS, float("inf"))
    for _ in range(rounds):
        for p, sac in sacs.items():
            start = time.perf_counter()
            for _ in range(updates):
                sac.update(x, a, r, x2)
            best[p] = min(best[p], (time.perf_counter() - start) / updates)
    return best


#: this process's timings where the cache could not be written, by (cache file, machine key,
#: choice): timed once per process, not at every run a sweep plans
_MEASURED: dict[tuple[str, str, str], tuple[str, dict[str, float]]] = {}


def _cache() -> tuple[Path, str, dict[str, Any]]:
    """``kernels.json``, this machine's key in it, and all it holds ({} when unreadable; a
    damaged entry of this machine left out, so its choices are timed again)."""
    path, key = cache_dir() / "kernels.json", machine_key()
    try:
        cached = json.loads(path.read_text())
    except (OSError, ValueError):
        cached = {}
    if not isinstance(cached, dict):
        cached = {}
    if not isinstance(cached.get(key, {}), dict):
        del cached[key]
    return path, key, cached


def _recorded(name: str) -> tuple[str, dict[str, float]] | None:
    """This machine's choice ``name`` and the timings behind it (this process's where the cache
    could not be written); None before it is timed."""
    path, key, cached = _cache()
    if (str(path), key, name) in _MEASURED:
        return _MEASURED[str(path), key, name]
    entry = cached.get(key, {})
    if name not in entry:
        return None
    times = entry.get(_seconds_key(name))
    sound = isinstance(times, dict) and all(
        is_number(t) and 0 < t < math.inf for t in times.values()
    )
    return entry[name], times if sound else {}  # (damaged timings: no note, not a traceback)


def _cached_choice(name: str, measure: Callable[[], tuple[str, dict[str, float]]]) -> str:
    """The choice ``name`` for this machine from ``kernels.json``, else ``measure()``d at one
    thread (as training runs) and cached with its timings."""
    found = _recorded(name)
    if found is not None:
        return found[0]
    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # as training runs
    try:
        choice, times = measure()
    finally:
        torch.set_num_threads(threads)
    path, key, cached = _cache()
    cached[key] = {**cached.get(key, {}), name: choice, _seconds_key(name): times}
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        write_text(path, json.dumps(cached, indent=2), shared=True)
    except OSError:  # an unwritable cache only means measuring again in the next process
        _MEASURED[str(path), key, name] = choice, times
    return choice


def _seconds_key(name: str) -> str:
    return "seconds" if name == "matmul" else f"{name}_seconds"


def choice_timings(name: str) -> dict[str, float]:
    """Seconds per option behind this machine's choice ``name`` (``matmul``: a layer's forward
    and backward; ``precision``: a SAC update), measured first if need be (once per process);
    {} where nothing was timed (no oneDNN op)."""
    (default_matmul if name == "matmul" else default_precision)()
    found = _recorded(name)
    return {} if found is None else found[1]


#: how much slower than this machine's choice a run's kernels are before a note says so
SLOW_KERNELS = 1.5


def slow_kernels(matmul: str, precision: str) -> list[tuple[str, float, str]]:
    """The settings among a run's ``matmul`` and ``precision`` that are ``SLOW_KERNELS`` times
    as slow as this machine's choice: (``"sac.precision=bfloat16"``, how many times as slow,
    the fastest option). A run keeps its kernels wherever it goes on: they decide how it
    rounds."""
    found = []
    for name, value in (("matmul", matmul), ("precision", precision)):
        times = choice_timings(name)
        fastest = min(times, key=times.__getitem__, default=None)
        if fastest and value in times and times[value] > SLOW_KERNELS * times[fastest]:
            setting = "matmul" if name == "matmul" else "sac.precision"
            found.append((f"{setting}={value}", times[value] / times[fastest], fastest))
    return found


def default_matmul() -> str:
    """The faster float32 library on this machine: ``onednn`` where its products are at least
    ``ONEDNN_SPEEDUP`` times as fast, else ``aten`` (also where oneDNN's op is missing);
    measured once and cached per ``machine_key``."""
    if not onednn_available():
        return "aten"

    def measure() -> tuple[str, dict[str, float]]:
        times = time_matmuls()
        fast = times["onednn"] * ONEDNN_SPEEDUP <= times["aten"]
        return ("onednn" if fast else "aten"), times

    choice = _cached_choice("matmul", measure)
    return choice if choice in MATMULS else "aten"


def default_precision() -> str:
    """``bfloat16`` where a SAC update with its products in bfloat16 is at least
    ``BF16_SPEEDUP`` times as fast as in float32 on this machine's float32 library (CPUs with
    bfloat16 units), else ``float32``; measured once and cached per ``machine_key``."""
    matmul = default_matmul()

    def measure() -> tuple[str, dict[str, float]]:
        times = time_precisions(matmul)
        fast = times["bfloat16"] * BF16_SPEEDUP <= times["float32"]
        return ("bfloat16" if fast else "float32"), times

    choice = _cached_choice("precision", measure)
    return choice if choice in PRECISIONS else "float32"


def _mm(a: torch.Tensor, b_t: torch.Tensor, bias: torch.Tensor | None = None) -> torch.Tensor:
    """a @ b_t.T (+ bias) on oneDNN; ``b_t`` is [out, in], as a linear layer's weight."""
    return torch.ops.mkldnn._linear_pointwise(a, b_t, bias, "none", [], "")


class _LinearFunction(torch.autograd.Function):
    """y = x W^T + b with x [B, in], W [out, in] (``nn.Linear``'s layout)."""

    @staticmethod
    def forward(ctx, x: torch.Tensor, weight: torch.Tensor, bias: torch.Tensor) -> torch.Tensor:
        ctx.save_for_backward(x, weight)
        return _mm(x, weight, bias)

    @staticmethod
    def backward(ctx, grad: torch.Tensor) -> tuple[torch.Tensor | None, ...]:
        x, weight = ctx.saved_tensors
        grad = grad.contiguous()
        gx = _mm(grad, weight.t()) if ctx.needs_input_grad[0] else None
        gw = _mm(grad.t(), x.t()) if ctx.needs_input_grad[1] else None
        gb = grad.sum(0) if ctx.needs_input_grad[2] else None
        return gx, gw, gb


class _EnsembleFunction(torch.autograd.Function):
    """y_i = x_i W_i + b_i with x [n, B, in], W [n, in, out], b [n, 1, out] (``EnsembleLinear``)."""

    @staticmethod
    def forward(ctx, x: torch.Tensor, weight: torch.Tensor, bias: torch.Tensor) -> torch.Tensor:
        ctx.save_for_backward(x, weight)
        return torch.stack([_mm(x[i], weight[i].t(), bias[i, 0]) for i in range(len(weight))])

    @staticmethod
    def backward(ctx, grad: torch.Tensor) -> tuple[torch.Tensor | None, ...]:
        x, weight = ctx.saved_tensors
        grad = grad.contiguous()
        n = len(weight)
        gx = gw = gb = None
        if ctx.needs_input_grad[0]:
            gx = torch.stack([_mm(grad[i], weight[i]) for i in range(n)])
        if ctx.needs_input_grad[1]:
            gw = torch.stack([_mm(x[i].t(), grad[i].t()) for i in range(n)])
        if ctx.needs_input_grad[2]:
            gb = grad.sum(1, keepdim=True)
        return gx, gw, gb


def _on_onednn(matmul: str, out_width: int) -> bool:
    return matmul == "onednn" and out_width >= MIN_WIDTH and not torch.is_autocast_enabled("cpu")


def linear(x: torch.Tensor, weight: torch.Tensor, bias: torch.Tensor, matmul: str) -> torch.Tensor:
    """``F.linear(x, weight, bias)``, on oneDNN when ``matmul`` says so; any leading dims."""
    if not _on_onednn(matmul, weight.shape[0]):
        return F.linear(x, weight, bias)
    flat = x.reshape(-1, x.shape[-1])
    return _LinearFunction.apply(flat, weight, bias).view(*x.shape[:-1], weight.shape[0])


def ensemble_linear(
    x: torch.Tensor, weight: torch.Tensor, bias: torch.Tensor, matmul: str
) -> torch.Tensor | None:
    """x_i W_i + b_i per ensemble member for ``onednn``, or None where ``aten``'s batched
    product should do it (a width-1 output never gets here: ``EnsembleLinear`` sums it)."""
    if matmul != "onednn" or torch.is_autocast_enabled("cpu"):
        return None
    return _EnsembleFunction.apply(x, weight, bias)


class Linear(nn.Linear):
    """``nn.Linear`` (same parameters and state dict) whose products follow ``matmul``."""

    def __init__(self, inp: int, out: int, matmul: str = "aten") -> None:
        super().__init__(inp, out)
        self.matmul = matmul

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return linear(x, self.weight, self.bias, self.matmul)
