"""The README's Python examples run as written (with smaller budgets), and it stays a guide."""

from __future__ import annotations

import re
from pathlib import Path

from fast_settings import FAST_AGENT

README = Path(__file__).resolve().parents[1] / "README.md"


def _python_blocks() -> list[str]:
    return re.findall(r"```python\n(.*?)```", README.read_text(), re.S)


def test_the_api_example_runs(tmp_path, monkeypatch):
    (block,) = [b for b in _python_blocks() if "SILI.load" in b]
    code = (
        block.replace("interactions=300", "interactions=4")
        .replace("interactions=20", "interactions=2")
        .replace('settings={"sac.lr": 3e-4}', f"settings={{'sac.lr': 3e-4, **{FAST_AGENT!r}}}")
    )
    monkeypatch.chdir(tmp_path)
    scope: dict = {}
    exec(compile(code, "README.md", "exec"), scope)
    assert scope["model"].agent.buffer.n >= 4  # trained, saved, loaded and played on
    assert (tmp_path / "runs" / "c3-api" / "checkpoint.pt").is_file()


def test_the_task_examples_run():
    (block,) = [b for b in _python_blocks() if "OracleObservation(" in b]
    scope: dict = {}
    exec(compile(block, "README.md", "exec"), scope)
    plain, oracle = scope["env"], scope["oracle_env"]
    assert oracle.observation_space.shape[0] == plain.observation_space.shape[0] + 2


def test_the_own_task_example_is_a_gymnasium_task_that_trains(tmp_path):
    from gymnasium.utils.env_checker import check_env

    from sili_robots import SILI

    (block,) = [b for b in _python_blocks() if "class TwoDoorsEnv" in b]
    scope: dict = {}
    exec(compile(block, "README.md", "exec"), scope)
    env = scope["TwoDoorsEnv"]()
    check_env(env, skip_render_check=True)
    door = env.reset(seed=0)[1]["strategy"][0]
    for _ in range(env.horizon):  # staying in the middle switches the door (T^z)
        env.step([0.0])
    assert env.reset()[1]["strategy"][0] == -door
    model = SILI(scope["TwoDoorsEnv"](), method="sili", settings=FAST_AGENT, run_dir=tmp_path / "r")
    assert model.learn(3).agent.buffer.n == 3


def test_the_readme_is_a_guide_not_a_notebook():
    from sili_robots.commands.claims import END, START

    text = README.read_text()
    lines = text.splitlines()
    claims = set(text.split(START, 1)[1].split(END, 1)[0].splitlines())  # a generated table's rows
    # a user's guide of one sitting: what, install, tasks, methods, CLI, API, figures, results
    assert len(lines) <= 360 and max(len(line) for line in lines if line not in claims) <= 200


def test_the_claims_table_is_generated_from_the_committed_results():
    from sili_robots.claims import claims_table, markdown
    from sili_robots.commands.claims import END, START
    from sili_robots.plot_data import load_results

    grid = README.parent / "results" / "paper-grid"
    table = markdown(claims_table(load_results(grid)))
    block = README.read_text().split(START, 1)[1].split(END, 1)[0]
    assert block.strip() == table.strip(), "run: sili claims results/paper-grid --write README.md"


def test_the_committed_results_are_not_ignored_by_git():
    """A clean clone must hold the runs the claims table is generated from."""
    import shutil
    import subprocess

    import pytest

    root = README.parent
    if shutil.which("git") is None or not (root / ".git").exists():
        pytest.skip("not a git checkout")
    runs = sorted((root / "results" / "paper-grid" / "runs").iterdir())
    assert len(runs) >= 166  # the grid's runs
    paths = [
        str((run / name).relative_to(root))
        for run in runs
        for name in ("config.json", "summary.json", "metrics.csv.gz")
    ]
    ignored = subprocess.run(
        ["git", "check-ignore", "--no-index", *paths], cwd=root, capture_output=True, text=True
    )
    assert ignored.returncode == 1, f"git ignores {ignored.stdout.split()[:5]}"
    tracked = subprocess.run(
        ["git", "ls-files", "results/paper-grid/runs"], cwd=root, capture_output=True, text=True
    ).stdout.split()
    assert set(paths) <= set(tracked), sorted(set(paths) - set(tracked))[:5]


def test_the_readmes_links_into_the_repository_lead_to_files():
    targets = re.findall(r"\]\(((?!https?:|#)[^)\s]+)\)", README.read_text())
    assert any(t.startswith("docs/preview-") for t in targets)  # the links are really read
    missing = [t for t in targets if not (README.parent / t.split("#")[0]).exists()]
    assert not missing
