"""Sweep specs: parsing, expansion into run configs, stable names, what is rejected up front."""

import json
import re

import pytest
from agent_helpers import flat_layout
from cli_helpers import sili as sili_in_process

from sili_robots.agent.config import AgentConfig
from sili_robots.agent.matmul import default_matmul
from sili_robots.agent.schedule import Schedule, value_at
from sili_robots.cli import main
from sili_robots.errors import ConfigError
from sili_robots.runs import run_differences, same_run
from sili_robots.sweep import SweepSpec, expand, parse_betas, parse_seeds, plan
from sili_robots.sweep.state import check_existing, record_invocation, recorded_specs, run_path


def _spec(**kw):
    base = {"tasks": ["circle-3"], "methods": ["sili"], "seeds": [0], "interactions": 5}
    return SweepSpec(**{**base, **kw})


def test_parse_seeds_ranges_lists_and_errors():
    assert parse_seeds("0-4") == [0, 1, 2, 3, 4]
    assert parse_seeds("0-2,7,1") == [0, 1, 2, 7]
    assert len(parse_seeds("0-5000,0-5000")) == 5001  # overlaps count once under the cap
    with pytest.raises(ConfigError, match="more than 10,000 runs per variant"):
        parse_seeds("0-5000,6000-12000")
    assert len(parse_seeds("0-9999")) == 10_000  # the cap itself is allowed, one more is not
    with pytest.raises(ConfigError, match="more than 10,000 runs per variant"):
        parse_seeds("0-10000")
    assert parse_seeds("3") == [3]
    with pytest.raises(ConfigError, match="'x'"):
        parse_seeds("0,x")
    with pytest.raises(ConfigError, match="empty"):
        parse_seeds("4-2")


def test_parse_betas_range_checked():
    assert parse_betas("0,0.2,1") == [0.0, 0.2, 1.0]
    with pytest.raises(ConfigError, match=r"1.5 is outside the allowed range \[0, 1\]"):
        parse_betas("0.5,1.5")
    with pytest.raises(ConfigError, match="bad b value 'a'"):
        parse_betas("a,b")


def test_expansion_is_the_cross_product_with_b_only_where_b_is_free():
    runs = expand(
        _spec(
            tasks=["circle-3", "circle-8"],
            methods=["sili", "lili", "sac"],
            seeds=[0, 1],
            betas=[0.2, 0.8],
            agent_overrides={"hidden": 32},
        )
    )
    # per task: sili x 2 b x 2 seeds + lili x 2 seeds + sac x 2 seeds
    assert len(runs) == 2 * (4 + 2 + 2)
    by_name = {r.name: r.config for r in runs}
    cfg = by_name["circle-8__sili-b0.2__s1"]
    assert (cfg.task, cfg.method, cfg.seed, cfg.agent.sili.beta) == ("circle-8", "sili", 1, 0.2)
    assert cfg.agent.hidden == 32 and cfg.interactions == 5
    assert by_name["circle-3__lili__s0"].agent.sili.beta == 0.0  # LILI's b stays 0
    assert by_name["circle-3__sac__s1"].agent.method == "sac"
    # the default b is part of SILI's name, so the b=0.5 run of a b sweep is the same run
    assert [r.name for r in expand(_spec())] == ["circle-3__sili-bschedule__s0"]
    assert "circle-3__sili-b0.5__s0" in {r.name for r in expand(_spec(betas=[0.5, 1.0]))}


def test_schedules_reach_every_run_and_b_schedules_only_where_b_is_free():
    spec = _spec(
        methods=["sili", "lili", "oracle"],
        beta_schedule=[(250, 0.0), (300, 0.5)],
        target_entropy_schedule=[(2000, -2.0), (2100, -4.0)],
        gamma_schedule=[(1600, 0.99), (1700, 0.998)],
        lr_schedule=[(2200, 3e-4), (2400, 3e-5)],
    )
    by_name = {r.name: r.config.agent for r in expand(spec)}
    names = {"circle-3__sili-bschedule__s0", "circle-3__lili__s0", "circle-3__oracle__s0"}
    assert set(by_name) == names
    sili = by_name["circle-3__sili-bschedule__s0"]
    assert [value_at(sili.sili.beta, i) for i in (0, 275, 1000)] == [0.0, 0.25, 0.5]
    assert not isinstance(by_name["circle-3__lili__s0"].sili.beta, Schedule)
    for agent in by_name.values():
        assert value_at(agent.sac.target_entropy, 2050) == -3.0
        assert value_at(agent.sac.gamma, 2000) == 0.998
        assert value_at(agent.sac.lr, 2300) == pytest.approx(1.65e-4)
    # the spec goes through sweep.json as JSON and plans the same runs again
    again = SweepSpec.from_dict(json.loads(json.dumps(spec.to_dict())))
    assert [r.config.to_dict() for r in expand(again)] == [r.config.to_dict() for r in expand(spec)]


def test_two_b_values_that_print_alike_are_refused_not_planned_under_one_name():
    """A name keeps b to 6 significant digits: two runs would share one folder."""
    assert {r.name for r in expand(_spec(betas=[0.123456, 0.123457]))} == {
        "circle-3__sili-b0.123456__s0",
        "circle-3__sili-b0.123457__s0",
    }
    with pytest.raises(
        ConfigError, match=r"two runs of this sweep would be named .*b0\.123456__s0"
    ):
        expand(_spec(betas=[0.1234561, 0.1234562]))


def test_names_are_stable_and_unique():
    spec = _spec(tasks=["circle-3", "speaker-listener"], methods=["sili", "smirl"], seeds=[0, 1, 2])
    a, b = [r.name for r in expand(spec)], [r.name for r in expand(spec)]
    assert a == b and len(set(a)) == len(a)


def test_controllers_multiply_only_tasks_that_take_one():
    runs = expand(
        _spec(tasks=["circle-3", "sawyer-reach"], methods=["sac"], controllers=["mink", "osc"])
    )
    names = [r.name for r in runs]
    assert names == ["circle-3__sac__s0", "sawyer-reach__sac__s0", "sawyer-reach-osc__sac__s0"]
    assert runs[0].config.env_kwargs == {}
    assert runs[2].config.env_kwargs == {"controller": "osc"}


def test_the_default_controller_swept_is_the_run_without_one():
    """A sweep's --controller mink,osc named its mink runs sawyer-reach-mink__...: the run a sweep
    without --controller names sawyer-reach__..., collected and counted as a second seed 0."""
    (plain,) = expand(_spec(tasks=["sawyer-reach"], methods=["sac"]))
    mink, osc = expand(_spec(tasks=["sawyer-reach"], methods=["sac"], controllers=["mink", "osc"]))
    assert mink.name == plain.name == "sawyer-reach__sac__s0"
    # a sweep made before resumes it, with or without --controller
    assert mink.former_names == plain.former_names == ("sawyer-reach-mink__sac__s0",)
    assert same_run(mink.config, plain.config, ())
    assert not same_run(osc.config, plain.config, ())
    assert run_differences(osc.config.to_dict(), plain.config.to_dict()) == [
        ("env_kwargs.controller", "osc", None)
    ]
    own = {"task": "sili_robots.examples.two_doors:TwoDoorsEnv", "task_id": None}
    given = {**own, "env_kwargs": {"horizon": 10}}  # a user's class: every argument counts
    assert run_differences(given, {**own, "env_kwargs": {}}) == [("env_kwargs.horizon", 10, None)]


def test_latent_kind_other_than_the_default_is_named():
    runs = expand(_spec(latent="continuous"))
    assert runs[0].name == "circle-3__sili-continuous-bschedule__s0"
    assert runs[0].config.agent.latent == "continuous"
    # speaker-listener's default latent is partial: not named
    assert (
        expand(_spec(tasks=["speaker-listener"]))[0].name == "speaker-listener__sili-bschedule__s0"
    )
    # LILI always learns a latent: a sweep's partial gives it the discrete one, as it always ran
    # (sili train --method lili --latent partial is refused instead)
    sili, lili = expand(
        _spec(tasks=["speaker-listener"], methods=["sili", "lili"], latent="partial")
    )
    assert (sili.config.agent.latent, lili.config.agent.latent) == ("partial", "discrete")
    assert lili.name == "speaker-listener__lili__s0"


def test_a_sweep_says_lili_learns_a_discrete_latent_where_it_asks_for_partial(tmp_path, capsys):
    """``sili train --method lili --latent partial`` is refused; a sweep of several methods
    gives LILI the discrete latent instead, and says so."""
    sweep = ["sweep", "--tasks", "circle-3", "--seeds", "0", "--dry-run", "--out", str(tmp_path)]
    assert main([*sweep, "--methods", "sili,lili", "--latent", "partial"]) == 0
    assert "--latent partial learns no latent strategy and LILI" in capsys.readouterr().err
    assert main([*sweep, "--methods", "sili,lili", "--latent", "continuous"]) == 0
    assert main([*sweep, "--methods", "sili,sac", "--latent", "partial"]) == 0
    assert "LILI" not in capsys.readouterr().err


def test_a_run_is_named_by_the_latent_it_learns_not_the_one_the_sweep_asked_for():
    """SAC learns no latent and LILI turns partial into discrete: the same run whatever
    --latent says, so the same name (earlier versions named it after --latent)."""
    plain = {r.config.method: r for r in expand(_spec(methods=["sili", "sac", "lili"]))}
    for latent, sili_name in (("continuous", "sili-continuous"), ("partial", "sili-partial")):
        runs = {
            r.config.method: r
            for r in expand(_spec(methods=["sili", "sac", "lili"], latent=latent))
        }
        assert runs["sili"].name == f"circle-3__{sili_name}-bschedule__s0"
        assert runs["sac"].name == "circle-3__sac__s0"
        assert runs["sac"].former_names == (f"circle-3__sac-{latent}__s0",)
        assert runs["sac"].config.to_dict() == plain["sac"].config.to_dict()
    assert runs["lili"].name == "circle-3__lili__s0" and runs["lili"].former_names == (
        "circle-3__lili-partial__s0",
    )
    assert runs["lili"].config.to_dict() == plain["lili"].config.to_dict()
    assert runs["sili"].former_names == () and plain["sac"].former_names == ()


@pytest.mark.parametrize(
    "kw,message",
    [
        ({"tasks": ["circle-9"]}, "unknown task 'circle-9'; allowed: circle-3"),
        ({"methods": ["ppo"]}, "unknown method 'ppo'; allowed: sili"),
        ({"methods": ["lili", "sac"], "betas": [0.2]}, "--beta applies to methods sili, smirl"),
        ({"controllers": ["osc"]}, "--controller applies to tasks sawyer-reach"),
        ({"agent_overrides": {"beta": 0.3}}, "use the sweep's --beta"),
        (
            {"agent_overrides": {"beta_schedule": {"points": [[0, 0.5]]}}},
            "use the sweep's --beta or --beta-schedule",
        ),
        (
            {
                "target_entropy_schedule": [(0, -2.0)],
                "agent_overrides": {"target_entropy_schedule": {"points": [[0, -2]]}},
            },
            "one of --set target_entropy_schedule and --target-entropy-schedule",
        ),
        ({"betas": [0.2], "beta_schedule": [(0, 0.5)]}, "one of --beta and --beta-schedule"),
        (
            {"gamma_schedule": [(0, 0.99)], "agent_overrides": {"gamma": 0.9}},
            "one of --set gamma and --discount-schedule",
        ),
        (
            {"lr_schedule": [(0, 3e-4)], "agent_overrides": {"lr": 1e-3}},
            "one of --set lr and --lr-schedule",
        ),
        ({"methods": ["lili"], "beta_schedule": [(0, 0.5)]}, "--beta-schedule applies to"),
        ({"beta_schedule": [(300, 0.5), (250, 0.0)]}, "interactions must increase"),
        ({"agent_overrides": {"hiddden": 3}}, "unknown setting 'hiddden'; allowed: latent, hidden"),
        ({"agent_overrides": {"gamma": 2}}, r"sac\.gamma must be in \[1e-09, 1\], got 2"),
        ({"latent": "fuzzy"}, "unknown latent kind 'fuzzy'"),
        ({"tasks": []}, "no tasks given"),
        ({"env_kwargs": {"controller": "osc"}}, "give controllers with --controller"),
    ],
)
def test_bad_specs_are_config_errors_naming_the_value(kw, message):
    with pytest.raises(ConfigError, match=message):
        expand(_spec(**kw))


def test_an_existing_run_with_other_settings_is_refused(tmp_path):
    (run,) = expand(_spec())
    path = run_path(tmp_path, run.name)
    path.mkdir(parents=True)
    other = run.config.to_dict()
    other["interactions"] = 99  # extended on its own: the sweep can be extended to match
    (path / "config.json").write_text(json.dumps({"run": other}))
    with pytest.raises(ConfigError, match=r"has 99 interactions, more than the 5 asked for now"):
        check_existing(tmp_path, run)
    with pytest.raises(ConfigError, match=r"ask for 99 \(--interactions 99\)$"):
        check_existing(tmp_path, run)
    other["interactions"] = 3  # a shorter run of a sweep: resuming the sweep extends it
    (path / "config.json").write_text(json.dumps({"run": other}))
    with pytest.raises(ConfigError, match=r"interactions: 3 on disk, 5 now\): a sweep never"):
        check_existing(tmp_path, run)  # not a sweep (no sweep.json): no --resume offered
    (tmp_path / "sweep.json").write_text("{}")
    said = (
        f"has 3 interactions, fewer than the 5 asked for now; extend the sweep's runs first "
        f"(sili sweep --resume {tmp_path} --interactions 5), then run this again"
    )
    with pytest.raises(ConfigError, match=re.escape(said)):
        check_existing(tmp_path, run)
    other["interactions"] = 99
    other["agent"]["sac"]["tau"] = 0.5  # and more: another run
    (path / "config.json").write_text(json.dumps({"run": other}))
    with pytest.raises(ConfigError, match=r"sac\.tau: 0\.5 on disk, .*; interactions: 99 on disk"):
        check_existing(tmp_path, run)
    saved = {**run.config.to_dict(), "checkpoint_every": run.config.checkpoint_every + 1}
    (path / "config.json").write_text(json.dumps({"run": saved}))
    check_existing(tmp_path, run)  # saved more often: the same run (it logs the same numbers)
    given = {**run.config.to_dict(), "env_kwargs": {"outside_margin": 0.2}}
    (path / "config.json").write_text(json.dumps({"run": given}))
    with pytest.raises(ConfigError, match=r"outside_margin: 0\.2 on disk, its default now\)"):
        check_existing(tmp_path, run)  # not None: the run was given no such argument
    (path / "config.json").write_text(json.dumps({"run": run.config.to_dict()}))
    check_existing(tmp_path, run)  # the same run: fine
    older = run.config.to_dict()
    # written before that setting existed: its default
    del older["agent"]["sili"]["smirl_std_floor"]
    (path / "config.json").write_text(json.dumps({"run": older}))
    check_existing(tmp_path, run)


def test_a_sweep_records_its_kernel_library_and_older_records_resume_on_aten(tmp_path, monkeypatch):
    spec = _spec(betas=[0.5])  # a constant b: the flat layout held no schedule
    assert spec.agent_overrides["matmul"] == default_matmul()
    assert SweepSpec.from_dict(spec.to_dict()) == spec
    recorded = spec.to_dict()
    del recorded["agent_overrides"]["matmul"]  # an invocation recorded before the setting
    older = SweepSpec.from_dict(recorded)
    (run,) = expand(older)
    assert run.config.agent.matmul == "aten"
    # its runs, whose config.json has no matmul either, are the same runs: resumable
    path = run_path(tmp_path, run.name)
    path.mkdir(parents=True)
    on_disk = flat_layout(run.config.to_dict())
    del on_disk["agent"]["matmul"]
    (path / "config.json").write_text(json.dumps({"run": on_disk}))
    check_existing(tmp_path, run)
    # planned anew on a machine whose timing chose oneDNN, they would be another sweep
    monkeypatch.setattr("sili_robots.sweep.spec.default_matmul", lambda: "onednn")
    (new,) = expand(_spec(betas=[0.5]))
    assert new.config.agent.matmul == "onednn"
    with pytest.raises(ConfigError, match=r"agent\.matmul: 'aten' on disk, 'onednn' now"):
        check_existing(tmp_path, new)


def test_plan_unions_specs_and_rejects_a_name_planned_twice_differently():
    runs = plan([_spec(), _spec(methods=["sili", "sac"])])
    assert [r.name for r in runs] == ["circle-3__sili-bschedule__s0", "circle-3__sac__s0"]
    with pytest.raises(ConfigError, match="planned twice"):
        plan([_spec(), _spec(interactions=6)])


def test_a_sweep_recorded_before_the_b_schedule_keeps_b_05_on_resume():
    recorded = _spec().to_dict()
    assert recorded["sili_beta"] == {"points": [[250, 0.0], [300, 0.5]]}
    del recorded["sili_beta"]  # as sweeps recorded it before SILI's default b was a schedule
    (run,) = expand(SweepSpec.from_dict(recorded))
    assert run.name == "circle-3__sili-b0.5__s0" and run.config.agent.sili.beta == 0.5


def test_a_sweep_recorded_before_raw_paper_latents_keeps_tanh_on_resume():
    spec = SweepSpec(
        tasks=["circle-continuous"], methods=["sili"], seeds=[0], interactions=3, profile="paper"
    )
    (run,) = expand(spec)
    assert run.config.agent.model.squash is False  # the paper's: the raw encoder output
    again = SweepSpec.from_dict(json.loads(json.dumps(spec.to_dict())))
    assert expand(again)[0].config == run.config
    recorded = spec.to_dict()
    del recorded["paper_raw_latents"]  # as sweeps recorded it before
    (old,) = expand(SweepSpec.from_dict(recorded))
    assert old.config.agent.model.squash is True and old.name == run.name


def test_a_sweep_records_the_changed_defaults_and_older_records_keep_the_earlier_value():
    spec = _spec(agent_overrides={})
    assert spec.agent_overrides["model.updates_per_interaction"] == 5
    (run,) = expand(spec)
    assert run.config.agent.model.updates_per_interaction == 5
    recorded = spec.to_dict()
    for path in ("model.updates_per_interaction", "sac.precision"):  # recorded before the change
        del recorded["agent_overrides"][path]
    (old,) = expand(SweepSpec.from_dict(recorded))
    assert old.config.agent.model.updates_per_interaction == 20
    # bfloat16 became a per-machine choice: an older record keeps float32 on any machine
    assert spec.agent_overrides["sac.precision"] == AgentConfig().sac.precision
    assert old.config.agent.sac.precision == "float32"
    # a value given by its earlier flat name is the user's, never replaced
    given = _spec(agent_overrides={"latent_updates_per_interaction": 7})
    assert "model.updates_per_interaction" not in given.agent_overrides
    assert expand(given)[0].config.agent.model.updates_per_interaction == 7


def test_a_new_sweep_builds_its_tasks_with_their_arguments_before_any_run(tmp_path):
    """A bad value stops the sweep at once (exit 2), in a dry run too, and leaves no folder."""
    out = tmp_path / "s"
    base = ["sweep", "--methods", "sac", "--seeds", "0", "--interactions", "2", "--out", str(out)]
    for args, message in (
        (["--tasks", "sawyer-reach", "--controller", "foo"], "unknown controller 'foo'"),
        (["--tasks", "circle-3", "--env-kwarg", "horizon=0"], "horizon=0"),
        (["--tasks", "circle-3", "--retries", "-1"], "argument --retries: -1 is not allowed"),
    ):
        for dry in ([], ["--dry-run"]):
            done = sili_in_process(*base, *args, *dry)  # argparse's errors too
            assert done.returncode == 2 and message in done.stderr and not out.exists()


def test_a_new_sweep_never_goes_into_a_folder_of_other_files(tmp_path, capsys):
    out = tmp_path / "mine"
    out.mkdir()
    (out / "results.csv").write_text("my own table\n")
    args = ["sweep", "--tasks", "circle-3", "--methods", "sac", "--out", str(out)]
    for dry in ([], ["--dry-run"]):
        assert main([*args, *dry]) == 2
        assert "is not a sweep or a results collection but holds files" in capsys.readouterr().err
    assert (out / "results.csv").read_text() == "my own table\n"


def _one_task(**kw) -> SweepSpec:
    return SweepSpec(**{"tasks": ["circle-3"], "methods": ["sili"], "seeds": [0], **kw})


def test_smirl_starts_from_the_package_profile_where_sili_starts_from_the_papers():
    (run,) = expand(_one_task(tasks=["driving"], methods=["smirl"], interactions=10))
    assert run.config.agent.profile == "package" and "-paper" not in run.name


def test_a_b_schedule_applies_to_smirl_too():
    (run,) = expand(
        _one_task(methods=["smirl"], interactions=10, beta_schedule=[(0, 0.0), (5, 0.5)])
    )
    assert isinstance(run.config.agent.sili.beta, Schedule)
    assert run.name == "circle-3__smirl-bschedule__s0"


def test_b_values_equal_as_numbers_are_one_b():
    assert parse_betas("0.5,0.50,5e-1") == [0.5]
    assert len(expand(_one_task(interactions=10, betas=parse_betas("0.5,0.50")))) == 1


def test_the_same_invocation_is_recorded_once(tmp_path):
    """Running a sweep again adds nothing to sweep.json; another invocation is appended."""
    record_invocation(tmp_path, _spec())
    record_invocation(tmp_path, _spec())
    record_invocation(tmp_path, SweepSpec.from_dict(json.loads(json.dumps(_spec().to_dict()))))
    assert recorded_specs(tmp_path) == [_spec()]
    record_invocation(tmp_path, _spec(seeds=[1]))
    record_invocation(tmp_path, _spec())
    invocations = json.loads((tmp_path / "sweep.json").read_text())["invocations"]
    assert [i["seeds"] for i in invocations] == [[0], [1]]


def test_a_run_planned_twice_keeps_the_first_invocations_plan():
    """Two invocations that differ in how often a run is saved: the first's plan goes on, as
    the run began."""
    (run,) = plan([_spec(checkpoint_every=4), _spec(checkpoint_every=9)])
    assert run.config.checkpoint_every == 4
    (run,) = plan([_spec(checkpoint_every=9), _spec(checkpoint_every=4)])
    assert run.config.checkpoint_every == 9
    runs = plan([_spec(checkpoint_every=4), _spec(seeds=[0, 1], checkpoint_every=9)])
    assert [(r.name, r.config.checkpoint_every) for r in runs] == [
        ("circle-3__sili-bschedule__s0", 4),
        ("circle-3__sili-bschedule__s1", 9),
    ]


def test_parse_seeds_checks_both_ends_of_a_range():
    with pytest.raises(ConfigError, match=r"seed 4294967296 is not allowed"):
        parse_seeds("4294967290-4294967296")
    assert parse_seeds("4294967290-4294967295")[-1] == 2**32 - 1  # the top seed itself is fine


def test_parse_betas_refuses_a_b_below_zero():
    with pytest.raises(ConfigError, match=r"b value -0.5 is outside the allowed range \[0, 1\]"):
        parse_betas("-0.5")
    assert parse_betas("0") == [0.0]
