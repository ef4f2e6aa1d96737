"""Resident memory of a run's latent refreshes: chunks padded to a few sizes (the agent,
``pad_rows``) against unpadded chunks (the reference: the agent before the padding), each in a
fresh process.

A refresh recomputes every cached latent (and, with ``latent_filter``, every per-step category)
over the replay in chunks of 512 interactions; the last chunk's size changes at every refresh.
Each new batch shape leaves memory behind in the process, so this measures what a real
agent holds after N interactions of a run, refreshing every 10 as in training. The stored
interactions are random (memory does not depend on their values) and no SAC update runs (its
batches have one fixed shape). Both variants must produce the same latents, bit for bit; the
script fails otherwise.

    python benchmarks/bench_refresh_memory.py [--interactions 1500] [--configs continuous,filter]
                                              [--matmul aten|onednn]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from sili_robots.agent.matmul import default_matmul, machine_key
from sili_robots.commands.common import positive_int
from sili_robots.errors import one_line_errors

CONFIGS = {
    "continuous": {"latent": "continuous", "latent_last_step": True},
    "filter": {"latent": "discrete", "latent_last_step": True, "latent_filter": 0.1},
}
H, OBS, ACT = 50, 3, 2  # Circle's interaction length and sizes


def rss_mib() -> float:
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20


def measure(config: str, padded: bool, interactions: int, matmul: str | None = None) -> dict:
    """One variant in this process: RSS after every 250 interactions, time, final latents."""
    import torch

    import sili_robots.addons.latent_filter as filter_module
    import sili_robots.agent.latent_cache as cache_module
    from sili_robots.addons import LatentFilter, build_addons
    from sili_robots.agent import SILIAgent
    from sili_robots.build import make_run_config

    torch.set_num_threads(1)
    if not padded:
        cache_module.pad_rows = lambda idx: idx  # the reference: chunks as they come ...
        filter_module.largest_power_of_two = lambda n: n  # ... and the filter's scale on all n
    settings = dict(CONFIGS[config], **({"matmul": matmul} if matmul else {}))
    cfg = make_run_config("circle-3", "sili", settings=settings)
    addons = build_addons(cfg.addons, cfg.agent)
    agent = SILIAgent(cfg.agent, OBS, ACT, H, strategy_dim=2, seed=0, addons=addons)
    rng = np.random.default_rng(0)
    rss, start = {}, time.perf_counter()
    for j in range(interactions):
        agent.observe_interaction(
            rng.normal(size=(H + 1, OBS)).astype(np.float32),
            rng.uniform(-1, 1, (H, ACT)).astype(np.float32),
            rng.normal(size=H).astype(np.float32),
            rng.normal(size=OBS).astype(np.float32),
            float(j % 3),
            {"strategy": np.zeros(2, np.float32)},
        )
        if (j + 1) % 250 == 0:
            rss[j + 1] = round(rss_mib())
    return {
        "rss": rss,
        "seconds": time.perf_counter() - start,
        "Z": agent.Z.tolist(),
        "ZF": [f.ZF.tolist() for f in agent.addons if isinstance(f, LatentFilter)][:1],
    }


def run_child(config: str, padded: bool, interactions: int, matmul: str | None) -> dict:
    cmd = [sys.executable, __file__, "--child", config, str(int(padded)), str(interactions)]
    cmd += ["--matmul", matmul] if matmul else []
    return json.loads(subprocess.run(cmd, check=True, capture_output=True, text=True).stdout)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    p.add_argument("--interactions", type=positive_int, default=1500)
    p.add_argument("--configs", default="continuous,filter")
    p.add_argument("--child", nargs=3, help=argparse.SUPPRESS)
    p.add_argument(
        "--matmul",
        choices=("aten", "onednn"),
        help="the latent model's products (default: the machine's choice, as a run makes it)",
    )
    args = p.parse_args()
    if args.child:  # its standard output is the JSON the parent reads, and nothing else
        config, padded, n = args.child
        print(json.dumps(measure(config, padded == "1", int(n), args.matmul)))
        return
    configs = args.configs.split(",")
    for config in configs:  # all before the first measurement (minutes each)
        if config not in CONFIGS:
            p.error(f"unknown config {config!r}; allowed: {', '.join(CONFIGS)}")
    print(f"machine: {machine_key()}", flush=True)  # every timing names its CPU
    print(f"the latent model's products on {args.matmul or default_matmul()}", flush=True)
    for config in configs:
        ref = run_child(config, False, args.interactions, args.matmul)
        new = run_child(config, True, args.interactions, args.matmul)
        print(f"{config}: resident MiB after N interactions (unpadded reference -> padded)")
        for n in ref["rss"]:
            r, a = ref["rss"][n], new["rss"][n]
            print(f"  {n:>5}: {r:>6} -> {a:>6}   ({r / a:.1f}x less)")
        dz = np.abs(np.array(ref["Z"]) - np.array(new["Z"])).max()
        same_zf = ref["ZF"] == new["ZF"]
        print(
            f"  time {ref['seconds']:.0f} s -> {new['seconds']:.0f} s; latents max difference "
            f"{dz:.1e}; filtered categories identical: {same_zf}",
            flush=True,
        )
        if dz > 0 or not same_zf:  # the padding must not change what the agent computes
            raise SystemExit(f"{config}: padded chunks changed the latents or the categories")


if __name__ == "__main__":
    one_line_errors(main, Path(__file__).name)
