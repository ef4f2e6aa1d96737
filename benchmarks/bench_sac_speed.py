"""SAC gradient updates per second: this package's SAC against stable-baselines3's SAC.

Same network sizes (2 x 256 actor and twin critics), same batch size and input width (a SILI
policy on Circle: state 3 + two 10-d latents), one process, one after the other, same torch
thread count, in rounds whose order reverses every other round. stable-baselines3's time
includes sampling its replay buffer (about 0.07 ms of its 13-17 ms), ours takes prepared
batches. Also reports seconds per learning interaction of ``sili train`` (SILI, Circle 3): each
setting runs twice (A B C C B A) and is set against stable-baselines3's 50 updates timed just
before and after it, so a drift in the machine's speed lands on both sides.

    python benchmarks/bench_sac_speed.py [--updates 300] [--threads 1] [--rounds 3]
    python benchmarks/bench_sac_speed.py --matmul-only   # the products alone, per library
    python benchmarks/bench_sac_speed.py --compile       # also a torch.compile'd update

It also prints the floor of the same arithmetic: the FLOP of the matrix products inside each
library's update (counted by ``torch.profiler``) at the rate of a 256 x 256 x 256 product in a
tight loop, the update's widest shape and its fastest in the profiles measured. It bounds the
time of our arithmetic on these kernels from below, so stable-baselines3's time over it bounds
the ratio an update doing that arithmetic can reach. The latent model's update is timed alone
and counted the same way, so the floor of a whole learning interaction (50 SAC updates and the
latent model's updates) is printed against stable-baselines3's time for its 50 updates.

Our SAC is timed in float32 with its float32 products on oneDNN (``matmul="onednn"``) and on
PyTorch's default BLAS (``matmul="aten"``, the kernels stable-baselines3 uses), both the same
arithmetic as stable-baselines3, and with ``precision="bfloat16"`` (matrix products under CPU
autocast). ``sili train`` is timed on the machine's default kernels (library and precision
chosen by timing, ``sili_robots/agent/matmul.py``) and on each float32 library.
``--compile`` adds float32 on aten with the update's two objectives (``SAC.critic_objective``,
``SAC.actor_objective``) compiled by ``torch.compile`` (inductor's CPU code, the optimizer steps
eager); its compile time is left out of the rate and printed beside it. Measured on torch 2.13
(benchmarks/RESULTS.md) it was slower than eager and its generated code crashed in 4 of 7 runs, so
the package does not compile.
"""

from __future__ import annotations

import argparse
import shutil
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import gymnasium as gym
import numpy as np
import torch

from sili_robots.commands.common import positive_int
from sili_robots.errors import one_line_errors

#: our variants: label -> (precision, matmul)
VARIANTS = {
    "float32, onednn": ("float32", "onednn"),
    "float32, aten": ("float32", "aten"),
    "bfloat16": ("bfloat16", "aten"),
}
COMPILED = "compiled, aten"


#: the profiler's names of the matrix products (linear layers, batched twin critics)
PRODUCTS = ("aten::mm", "aten::bmm", "aten::addmm", "aten::baddbmm")


def product_gflop(run: Callable[[], object], calls: int) -> float:
    """GFLOP of matrix products per call of ``run``, as torch.profiler counts them."""
    from torch.profiler import ProfilerActivity, profile

    with profile(activities=[ProfilerActivity.CPU], with_flops=True) as prof:
        run()
    return sum(e.flops for e in prof.key_averages() if e.key in PRODUCTS) / 1e9 / calls


def make_ours(
    in_dim: int, act_dim: int, precision: str = "float32", matmul: str = "aten"
) -> object:
    from sili_robots.agent.sac import SAC

    return SAC(in_dim, act_dim, hidden=256, precision=precision, matmul=matmul)


def ours_batches(
    in_dim: int, act_dim: int, batch: int, updates: int
) -> list[tuple[torch.Tensor, ...]]:
    g = torch.Generator().manual_seed(0)
    x = torch.randn(updates, batch, in_dim, generator=g)
    a = torch.rand(updates, batch, act_dim, generator=g) * 2 - 1
    r = torch.randn(updates, batch, generator=g)
    x2 = torch.randn(updates, batch, in_dim, generator=g)
    return list(zip(x, a, r, x2, strict=True))


def time_ours(
    in_dim: int,
    act_dim: int,
    batch: int,
    updates: int,
    precision: str,
    matmul: str,
    compiled: bool = False,
    warmup_seconds: list[float] | None = None,
) -> float:
    sac = make_ours(in_dim, act_dim, precision, matmul)
    if compiled:
        sac.critic_objective = torch.compile(sac.critic_objective, dynamic=False)
        sac.actor_objective = torch.compile(sac.actor_objective, dynamic=False)
    batches = ours_batches(in_dim, act_dim, batch, updates)
    t = time.perf_counter()
    for b in batches[:10]:
        sac.update(*b)
    if warmup_seconds is not None:
        warmup_seconds.append(time.perf_counter() - t)
    t = time.perf_counter()
    for b in batches:
        sac.update(*b)
    return updates / (time.perf_counter() - t)


def make_sb3(in_dim: int, act_dim: int, batch: int) -> object:
    """stable-baselines3's SAC on a dummy env, its buffer filled and its first updates done."""
    from stable_baselines3 import SAC as SB3SAC
    from stable_baselines3.common.logger import Logger

    class Dummy(gym.Env):
        observation_space = gym.spaces.Box(-np.inf, np.inf, (in_dim,), np.float32)
        action_space = gym.spaces.Box(-1, 1, (act_dim,), np.float32)

        def reset(self, *, seed=None, options=None):
            return np.zeros(in_dim, np.float32), {}

        def step(self, action):
            return np.zeros(in_dim, np.float32), 0.0, False, False, {}

    model = SB3SAC(
        "MlpPolicy",
        Dummy(),
        batch_size=batch,
        learning_starts=0,
        device="cpu",
        policy_kwargs={"net_arch": [256, 256]},
        seed=0,
        buffer_size=10_000,
    )
    rng = np.random.default_rng(0)
    for _ in range(5_000):
        model.replay_buffer.add(
            rng.normal(size=(1, in_dim)).astype(np.float32),
            rng.normal(size=(1, in_dim)).astype(np.float32),
            rng.uniform(-1, 1, (1, act_dim)).astype(np.float32),
            rng.normal(size=1).astype(np.float32),
            np.zeros(1),
            [{}],
        )
    # a silent logger of its own: without one, _setup_learn makes an empty SB3-<time> folder in
    # the temporary directory on every call
    model.set_logger(Logger(folder=None, output_formats=[]))
    model._setup_learn(total_timesteps=1)
    model.train(gradient_steps=10, batch_size=batch)
    return model


def time_sb3(in_dim: int, act_dim: int, batch: int, updates: int) -> float:
    model = make_sb3(in_dim, act_dim, batch)
    t = time.perf_counter()
    model.train(gradient_steps=updates, batch_size=batch)
    return updates / (time.perf_counter() - t)


def latent_step(
    obs_dim: int, act_dim: int, horizon: int, matmul: str = "aten"
) -> Callable[[], float]:
    """One update of the default latent model (``model.batch`` interaction pairs of
    ``horizon`` steps) on fixed random data, as ``SILIAgent.update_latent_model`` makes it."""
    from sili_robots.agent.config import AgentConfig
    from sili_robots.agent.latent import LatentModel
    from sili_robots.agent.schedule import value_at

    cfg = AgentConfig()
    torch.manual_seed(0)
    model = LatentModel(obs_dim, act_dim, cfg.model.dim, cfg.hidden, "discrete", matmul=matmul)
    opt = torch.optim.Adam(model.parameters(), lr=value_at(cfg.model.lr, 0))
    n = cfg.model.batch
    prev = torch.randn(n, horizon, 2 * obs_dim + act_dim + 1)
    obs, act = torch.randn(n, horizon + 1, obs_dim), torch.rand(n, horizon, act_dim) * 2 - 1
    rew = torch.randn(n, horizon)

    def step() -> float:
        loss = model.loss(prev, obs[:, :-1], act, obs[:, 1:], rew)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        return float(loss.detach())

    return step


def time_latent(matmul: str, updates: int, obs_dim: int = 3, act_dim: int = 2) -> float:
    """Seconds per latent-model update on Circle (3 Goals)'s shapes (horizon 50)."""
    step = latent_step(obs_dim, act_dim, 50, matmul)
    for _ in range(3):
        step()
    t = time.perf_counter()
    for _ in range(updates):
        step()
    return (time.perf_counter() - t) / updates


def update_gflop(in_dim: int, act_dim: int, batch: int) -> dict[str, float]:
    """GFLOP of matrix products per update: our SAC's (float32 on aten), stable-baselines3's
    and our latent model's (Circle (3 Goals)'s shapes)."""
    sac = make_ours(in_dim, act_dim)
    batches = ours_batches(in_dim, act_dim, batch, 2)
    model = make_sb3(in_dim, act_dim, batch)
    step = latent_step(3, 2, 50)
    return {
        "ours": product_gflop(lambda: [sac.update(*b) for b in batches], len(batches)),
        "sb3": product_gflop(lambda: model.train(gradient_steps=2, batch_size=batch), 2),
        "latent": product_gflop(lambda: [step() for _ in range(2)], 2),
    }


def time_train(
    interactions: int, precision: str, matmul: str, threads: int = 1, **extra: object
) -> float:
    """Seconds per learning interaction of ``sili train`` (SILI, Circle 3, the default agent
    unless ``extra`` settings say otherwise), from the run's own wall times after its random
    phase (5 interactions here)."""
    import pandas as pd

    from sili_robots.build import make_run_config
    from sili_robots.training import train

    out = Path(tempfile.mkdtemp())
    settings = {"sac.random_interactions": 5, "sac.precision": precision, "matmul": matmul}
    settings.update(extra)
    cfg = make_run_config("circle-3", "sili", 0, interactions, settings=settings, threads=threads)
    train(cfg, out, progress=False)
    wall = pd.read_csv(out / "metrics.csv")["wall_time"].to_numpy()
    shutil.rmtree(out)
    return float((wall[-1] - wall[5]) / (len(wall) - 6))


def machine() -> str:
    """CPU model, its vector extensions and any instruction-set cap (``ATEN_CPU_CAPABILITY``
    and the like, which emulate an older processor), as every timing here is reported with."""
    from sili_robots.agent.matmul import isa_caps, machine_key

    model, flags, *_ = machine_key().split(" | ")
    caps = [f"capped: {v}={value}" for v, value in isa_caps().items()]
    return "; ".join([model, flags or "flags unknown", *caps])


def time_matmul(m: int, k: int, n: int, matmul: str, repeats: int = 2000) -> float:
    """GFLOP/s of a float32 [m, k] x [k, n] product plus bias, as a linear layer computes it."""
    from sili_robots.agent.matmul import linear

    x, w, b = torch.randn(m, k), torch.randn(n, k), torch.randn(n)
    for _ in range(50):
        linear(x, w, b, matmul)
    t = time.perf_counter()
    for _ in range(repeats):
        linear(x, w, b, matmul)
    return 2 * m * k * n * repeats / (time.perf_counter() - t) / 1e9


def matmul_only() -> None:
    print("float32 linear layer, one thread (GFLOP/s; oneDNN / aten)")
    for m, k, n in ((256, 256, 256), (256, 25, 256), (1600, 256, 256)):
        aten, dnn = time_matmul(m, k, n, "aten"), time_matmul(m, k, n, "onednn")
        print(f"  [{m}, {k}] x [{k}, {n}]: aten {aten:6.1f}  onednn {dnn:6.1f}  {dnn / aten:.2f}x")


def main() -> None:
    from sili_robots.agent.config import AgentConfig
    from sili_robots.agent.matmul import default_matmul, default_precision
    from sili_robots.build import make_run_config
    from sili_robots.commands.common import parse_settings
    from sili_robots.errors import ConfigError

    p = argparse.ArgumentParser()
    p.add_argument("--updates", type=positive_int, default=300)
    p.add_argument("--threads", type=positive_int, default=1)
    p.add_argument("--interactions", type=positive_int, default=30)
    p.add_argument(
        "--rounds", type=positive_int, default=3, help="alternating rounds; medians reported"
    )
    p.add_argument("--matmul-only", action="store_true", help="time the products alone")
    p.add_argument("--compile", action="store_true", help="also time a torch.compile'd update")
    p.add_argument(
        "--arm",
        action="append",
        default=[],
        metavar="KEY=VALUE[;KEY=VALUE]",
        help="also time sili train with these agent settings (on the machine's default "
        "kernels), e.g. model.updates_per_interaction=20; repeatable",
    )
    args = p.parse_args()
    if args.interactions < 7:  # 5 random interactions, then at least 2 learning ones to time
        p.error(f"--interactions {args.interactions}: need at least 7")
    arms = {}  # checked now, not after minutes of timing
    for arm in args.arm:
        try:
            arms[arm] = parse_settings(arm.split(";"))
            make_run_config("circle-3", "sili", 0, args.interactions, settings=arms[arm])
        except ConfigError as err:
            p.error(f"--arm {arm!r}: {err}")
    torch.set_num_threads(args.threads)
    if args.matmul_only:
        print(f"machine: {machine()}")  # every timing names its CPU
        matmul_only()
        return
    in_dim, act_dim, batch = 3 + 2 * 10, 2, 256
    variants = {label: (p, m, False) for label, (p, m) in VARIANTS.items()}
    if args.compile:
        variants[COMPILED] = ("float32", "aten", True)
    rates: dict[str, list[float]] = {"sb3": [], **{label: [] for label in variants}}
    compile_seconds: list[float] = []
    peak: list[float] = []  # GFLOP/s of the update's widest product, in a tight loop
    order = ["sb3", *variants]
    for r in range(args.rounds):  # alternate, reversed every other round: no arm always first
        for label in order if r % 2 == 0 else order[::-1]:
            if label == "sb3":
                rates["sb3"].append(time_sb3(in_dim, act_dim, batch, args.updates))
                continue
            precision, matmul, compiled = variants[label]
            warmup = compile_seconds if compiled else None
            rate = time_ours(
                in_dim, act_dim, batch, args.updates, precision, matmul, compiled, warmup
            )
            rates[label].append(rate)
        peak.append(time_matmul(256, 256, 256, "aten", repeats=1000))
    med = {k: float(np.median(v)) for k, v in rates.items()}
    sb3 = med["sb3"]
    print(f"machine: {machine()}")
    print(f"torch threads: {args.threads}; batch {batch}; input {in_dim}; 2 x 256 networks")
    print(f"stable-baselines3 SAC:              {sb3:8.1f} updates/s ({1e3 / sb3:.2f} ms/update)")
    for label in variants:
        ours = med[label]
        print(
            f"sili_robots SAC, {label:16s}: {ours:8.1f} updates/s "
            f"({1e3 / ours:.2f} ms/update), {ours / sb3:.2f}x stable-baselines3"
        )
    if compile_seconds:
        print(f"({COMPILED}: first 10 updates, compiling included, {max(compile_seconds):.1f} s)")
    print(f"(medians of {args.rounds} alternating rounds)")
    sb3_50 = 50 / sb3  # stable-baselines3's time for one interaction's 50 SAC updates
    gflop, rate = update_gflop(in_dim, act_dim, batch), max(peak)
    floor = gflop["ours"] / rate  # seconds per update, products only, all at the best rate
    print(
        f"floor: our update's products {gflop['ours']:.3f} GFLOP (stable-baselines3's "
        f"{gflop['sb3']:.3f}) at {rate:.0f} GFLOP/s ([256, 256] x [256, 256] in a loop) = "
        f"{1e3 * floor:.2f} ms: at most {1 / sb3 / floor:.2f}x stable-baselines3's update, "
        f"50 of them at least {50 * floor / sb3_50:.2f}x its 50 updates"
    )
    precision, matmul = default_precision(), default_matmul()
    per = AgentConfig().model.updates_per_interaction
    latent = per * float(np.median([time_latent(matmul, 20) for _ in range(args.rounds)]))
    sac_50 = 50 / med[f"float32, {matmul}"]  # on the same products as the latent model
    print(
        f"latent model, {per} updates of {gflop['latent']:.3f} GFLOP on {matmul}: "
        f"{latent:.3f} s per interaction, {latent / sac_50:.2f}x our 50 float32 SAC updates "
        f"on {matmul}"
    )
    work = 50 * gflop["ours"] + per * gflop["latent"]
    print(
        f"floor of a learning interaction: {work:.1f} GFLOP of products (50 SAC updates, "
        f"{per} latent-model updates) at {rate:.0f} GFLOP/s = {work / rate:.3f} s, at least "
        f"{work / rate / sb3_50:.2f}x stable-baselines3's 50 updates"
    )
    runs = [(f"default: {precision}, {matmul}", precision, matmul, {})]
    runs += [(label, p, m, {}) for label, (p, m) in VARIANTS.items() if p == "float32"]
    for arm, settings in arms.items():  # the default kernels unless the arm sets them
        runs.append((arm, precision, matmul, settings))
    # each run twice, in the order A B C C B A, each time between two timings of
    # stable-baselines3's 50 updates: its own reference, taken minutes apart from no other
    seconds: dict[str, list[float]] = {label: [] for label, *_ in runs}
    reference: dict[str, list[float]] = {label: [] for label, *_ in runs}
    before = 50 / time_sb3(in_dim, act_dim, batch, args.updates)
    for label, precision, matmul, extra in [*runs, *runs[::-1]]:
        seconds[label].append(
            time_train(args.interactions, precision, matmul, args.threads, **extra)
        )
        after = 50 / time_sb3(in_dim, act_dim, batch, args.updates)
        reference[label].append((before + after) / 2)
        before = after
    for label, *_ in runs:
        took, ref = float(np.mean(seconds[label])), float(np.mean(reference[label]))
        print(
            f"sili train, SILI on circle-3, {label:24s}: {took:.3f} s per learning "
            f"interaction ({', '.join(f'{x:.3f}' for x in seconds[label])}), {took / ref:.2f}x "
            f"stable-baselines3's 50 updates timed beside it ({ref:.3f} s)"
        )


if __name__ == "__main__":
    one_line_errors(main, Path(__file__).name)
