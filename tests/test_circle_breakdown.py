"""The Circle breakdown's counterfactual endings, on a short real run: the rewritten interaction
ends where asked, endings inside are played against the opponent moved on, and the replay's
endings near the edge are counted on the right side."""

from __future__ import annotations

from pathlib import Path
from types import ModuleType

import numpy as np
import pytest
import torch
from benchmark_scripts import load_script
from fast_settings import FAST_ARGS

from sili_robots.cli import main
from sili_robots.tasks import make_task
from sili_robots.tasks.circle import STEP


@pytest.fixture(scope="module")
def breakdown() -> ModuleType:
    return load_script("circle_reward_breakdown")


@pytest.fixture(scope="module")
def run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("breakdown") / "run"
    args = ["train", "--task", "sili/Circle3-v0", "--method", "sili", "--latent", "continuous"]
    args += ["--interactions", "8", "--seed", "0", "--out", str(out), "--no-progress"]
    assert main([*args, "--set", "latent_last_step=true", *FAST_ARGS]) == 0
    return out


def test_rewritten_interaction_ends_where_asked(breakdown: ModuleType, run: Path) -> None:
    agent, task, _ = breakdown.load_run(run)
    location = 0
    goal = np.array([np.cos(task.angles[location]), np.sin(task.angles[location])])
    finals = np.array([[[0.0, 0.95]], [[0.0, 1.07]]], np.float32)
    traj = breakdown.rewritten_last_interaction(agent, task, location, finals, 1)
    b, j = agent.buffer, agent.buffer.n - 1
    obs_dim = b.obs.shape[-1]
    played = torch.cat(
        [torch.from_numpy(x[j]) for x in (b.obs[:, :-1], b.act, b.rew[..., None], b.obs[:, 1:])],
        -1,
    )
    assert torch.equal(traj[0], played)  # row 0 is the interaction as played
    last = traj[1:, -1]
    next_pos = last[:, -obs_dim:][:, :2].numpy()
    np.testing.assert_allclose(next_pos, finals[:, 0])
    reward = last[:, obs_dim + 2].numpy()  # after s (obs_dim) and a (2)
    np.testing.assert_allclose(reward, -np.linalg.norm(finals[:, 0] - goal, axis=-1), rtol=1e-6)
    action = last[:, obs_dim : obs_dim + 2].numpy()
    prev = last[:, :2].numpy()
    expected = np.clip((finals[:, 0] - prev) / STEP, -1, 1)
    np.testing.assert_allclose(action, expected, rtol=1e-5, atol=1e-6)
    assert torch.equal(traj[1:, :-1], played[None, :-1].expand(2, -1, -1))  # earlier steps kept


def test_ending_inside_is_played_against_the_moved_on_opponent(
    breakdown: ModuleType, run: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    agent, task, _ = breakdown.load_run(run)
    played_at: list[int] = []

    def record(agent: object, task: object, location: int, z: np.ndarray) -> float:
        played_at.append(location)
        return -float(location)

    monkeypatch.setattr(breakdown, "greedy_interaction", record)
    dz, rewards, as_played = breakdown.ending_cost(agent, task, 2)
    radii = breakdown.exit_radii(task)
    assert dz.shape == rewards.shape == radii.shape
    assert played_at[0] == 2 and as_played == -2.0
    np.testing.assert_array_equal(played_at[1:], np.where(radii < 1, 0, 2))  # 2 -> 0 moved on


def test_a_greedy_interaction_is_played_against_the_given_location(
    breakdown: ModuleType, run: Path
) -> None:
    agent, task, _ = breakdown.load_run(run)
    z = np.zeros(agent.zdim * agent.n_latents, np.float32)
    played = []
    for location in range(3):
        got = breakdown.greedy_interaction(agent, task, location, z)
        obs, _ = task.reset(options={"strategy": location})
        total = 0.0
        for _ in range(task.horizon):
            x = torch.from_numpy(np.concatenate([obs, z]).astype(np.float32)).unsqueeze(0)
            obs, reward, _, _, _ = task.step(agent.sac.act(x, deterministic=True)[0].numpy())
            total += reward
        assert got == pytest.approx(total)
        played.append(got)
    assert len(set(played)) == 3  # the same play, against three places


@pytest.mark.parametrize(("version", "rim"), [("v0", 1.0), ("v1", 1.1)])
def test_probes_straddle_the_tasks_edge(breakdown: ModuleType, version: str, rim: float) -> None:
    task = make_task(f"sili/Circle3-{version}").unwrapped
    assert breakdown.edge(task) == pytest.approx(rim)
    radii = breakdown.exit_radii(task)
    inside = np.array([task.ends_inside(np.array([r, 0.0])) for r in radii])
    assert inside.any() and not inside.all()  # some counterfactual exits on each side
    np.testing.assert_array_equal(inside, radii < rim)


def test_edge_examples_count_each_side_near_the_location(breakdown: ModuleType, run: Path) -> None:
    agent, task, metrics = breakdown.load_run(run)
    location = 1
    direction = np.array([np.cos(task.angles[location]), np.sin(task.angles[location])])
    other = np.array([np.cos(task.angles[0]), np.sin(task.angles[0])])
    agent.buffer.obs[:, -1, :2] = 0.0  # every stored interaction ends at the centre ...
    placed = {0: 0.97 * direction, 1: 1.03 * direction, 2: 1.04 * direction, 3: 0.98 * other}
    placed |= {4: 1.2 * direction}  # ... but these (4: outside the band)
    for j, final in placed.items():
        agent.buffer.obs[j, -1, :2] = final
    metrics["strategy_id"] = location
    metrics.loc[2, "strategy_id"] = 0  # the opponent was elsewhere: not an example
    assert breakdown.edge_examples(agent, task, metrics, location) == (1, 1)


def test_slip_cost_plays_the_held_and_the_moved_on_opponent(run: Path) -> None:
    slip = load_script("circle_slip_cost")
    out = slip.slip_costs(run, eps=0.01, noise=0.25, plays=1)
    plain, filtered = out["no filter"], out["filter"]
    assert all(step == -1 for rows in plain.values() for _, step in rows)  # never leaves z
    # deterministic plays: the opponent's location decides the reward ...
    assert plain["held"][-1][0] != pytest.approx(plain["moved on"][-1][0])
    # ... and a filter that never leaves z plays exactly as the policy without it
    for case in ("held", "moved on"):
        reward, step = filtered[case][-1]
        assert -1 <= step < 50
        if step == -1:
            assert reward == pytest.approx(plain[case][-1][0])


def test_a_run_without_its_checkpoint_is_one_line_not_a_traceback() -> None:
    """The grid's committed runs keep no checkpoint; the script says so and exits 2."""
    import subprocess
    import sys

    from benchmark_scripts import BENCHMARKS

    run = BENCHMARKS.parent / "results" / "paper-grid" / "runs" / "circle-3__sili-bschedule__s2"
    done = subprocess.run(
        [sys.executable, str(BENCHMARKS / "circle_reward_breakdown.py"), str(run)],
        capture_output=True,
        text=True,
    )
    assert done.returncode == 2 and "Traceback" not in done.stderr
    assert done.stderr.startswith("circle_reward_breakdown.py: error: ") and "checkpoint.pt" in (
        done.stderr
    )
