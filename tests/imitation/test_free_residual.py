"""Learning where tracking fails: the smoothed-reference baseline on real PyBullet,
and experiment=signs_free_residual end to end on a tiny budget (real runs, the residual table with the
controller, the pinned base, the smoothed baselines and the verdict, all under the policy's protocol)."""

from __future__ import annotations

import csv
import json
import shutil
import sys

import numpy as np
import pytest
import job_process

from aslexp.envs.imitation import ImitationEnv
from aslexp.rl.evaluate import constant_correction_policy, evaluate, reference_policy, smoothed_reference_policy

from .test_jobs import run_job

FIXED = {"reference_state_init": False, "early_termination": {"min_reward": None}}


def test_smoothing_alpha_zero_is_the_reference_one_step_ahead(motion_a):
    env = ImitationEnv(motion_a, env={**FIXED, "action_mode": "residual", "normalize_actions": True,
                                      "residual_range": 0.5})
    plain = evaluate(env, reference_policy(1), 30, phase=0.2)
    same = evaluate(env, smoothed_reference_policy(0.0), 30, phase=0.2)
    assert same.mean_reward == pytest.approx(plain.mean_reward, abs=1e-6)
    smooth = evaluate(env, smoothed_reference_policy(0.6), 30, phase=0.2)
    assert abs(smooth.mean_reward - plain.mean_reward) > 1e-3  # the filter changes the targets
    # The filter restarts with each episode: the same episode twice scores the same.
    policy = smoothed_reference_policy(0.6)
    first, second = evaluate(env, policy, 30, phase=0.2), evaluate(env, policy, 30, phase=0.2)
    assert first.mean_reward == second.mean_reward
    env.close()


def test_smoothing_groups_select_joints_and_fail_clearly(motion_a):
    env = ImitationEnv(motion_a, env={**FIXED, "action_mode": "residual", "residual_range": 0.5})
    env.reset(options={"time": 0.3})
    thumb = smoothed_reference_policy(0.9, ("thumb",))
    env.step(thumb(None, env))
    action = thumb(None, env)  # the second step: only the thumb's targets lag the reference
    moved = np.flatnonzero(np.abs(action) > 1e-9)
    thumb_columns = [i for i, j in enumerate(env.layout.joints) if j.group == "thumb"]
    assert len(moved) and set(moved) <= set(thumb_columns)
    with pytest.raises(ValueError, match=r"no joint in groups \['toes'\]; the body's groups are \["):
        smoothed_reference_policy(0.5, ("toes",))(None, env)
    with pytest.raises(ValueError, match=r"alpha must be in \[0, 1\)"):
        smoothed_reference_policy(1.0)
    env.close()


def test_a_constant_random_correction_has_the_asked_size_and_holds_still(motion_a):
    env = ImitationEnv(motion_a, env={**FIXED, "action_mode": "residual", "residual_range": 0.5,
                                      "normalize_actions": True})
    actions = []
    draw = constant_correction_policy(0.04, seed=3)
    run = evaluate(env, lambda obs, e: actions.append(draw(obs, e)) or actions[-1], 10)
    assert run.action_rms == pytest.approx(0.04, rel=1e-5) and all(np.array_equal(a, actions[0]) for a in actions)
    assert not np.array_equal(actions[0], constant_correction_policy(0.04, seed=4)(None, env))
    np.testing.assert_array_equal(actions[0], constant_correction_policy(0.04, seed=3)(None, env))
    from aslexp.compose import resolve_group

    absolute = ImitationEnv(motion_a, env={**resolve_group("env", "default"), **FIXED})  # absolute targets
    with pytest.raises(ValueError, match="need a residual action"):
        constant_correction_policy(0.04, seed=3)(None, absolute)
    env.close(), absolute.close()


TINY = ["ppo.hidden_sizes=[32,32]", "ppo.steps_per_rollout=64", "ppo.minibatch_size=64", "ppo.epochs=1",
        "ppo.total_steps=64", "ppo.eval_interval=64", "ppo.eval_steps=12", "ppo.eval_episodes=2",
        "ppo.critic_warmup_steps=0", "ppo.num_envs=1", "plots=false", "render.gif=false",
        "report.residual.smoothing=[0.6]", "report.residual.random_corrections.count=2"]


def test_signs_free_residual_runs_end_to_end(tmp_path):
    sweep = tmp_path / "residual"
    ran = run_job("imitate", "-m", "experiment=signs_free_residual", "motion='52861'", "seed=0,1", *TINY,
                  f"hydra.sweep.dir={sweep}")
    # The baselines take minutes per sign at full size: each evaluation is a progress line with an ETA.
    # (controller, its drift, one smoothing alpha, two random corrections, the pinned base)
    assert "residual baselines 52861: 6/6 evaluations" in ran.stdout + ran.stderr
    resolved = (sweep / "0" / ".hydra" / "config.yaml").read_text()
    assert "base: free" in resolved and "mode: stable_pd" in resolved and "action_mode: residual" in resolved
    with open(sweep / "residual_table.csv", newline="", encoding="utf-8") as fh:
        [row] = list(csv.DictReader(fh))
    assert row["sign"] == "52861 (snow)" and row["learned, last evaluation"].endswith("(n=2)")
    stored = json.loads((sweep / "residual_baselines.json").read_text())["52861"]
    # The controller row is the runs' own zero-correction baseline, under the same protocol.
    metrics = json.loads((sweep / "0" / "metrics.json").read_text())
    assert stored["controller"] == pytest.approx(metrics["baselines"]["lookahead"], abs=1e-9)
    assert float(row["controller"]) == pytest.approx(stored["controller"], abs=5e-4)
    assert 0 < stored["controller"] <= 1 and 0 < stored["compare"] <= 1 and set(stored["smoothed"]) == {"0.6"}
    chance = stored["random_corrections"]  # two fixed random corrections of RMS 0.04: chance
    assert chance["seeds"] == [0, 1] and chance["rms"] == 0.04 and len(set(chance["scores"])) == 2
    assert row["constant random corrections, RMS 0.04 (n=2): mean ± std / best"] == "{:.3f} ± {:.3f} / {:.3f}".format(
        np.mean(chance["scores"]), np.std(chance["scores"]), max(chance["scores"]))
    drift = stored["controller_drift"]  # where the root went under the controller, from phase 0
    assert 0 <= drift["max_tilt_deg"] < 90 and 0 <= drift["max_yaw_deg"] <= 180
    assert row["controller from phase 0: max yaw / tilt (deg)"] == (
        f"{drift['max_yaw_deg']:.1f} / {drift['max_tilt_deg']:.1f}")
    loss = float(row["loss to the physical cause"])
    assert loss == pytest.approx(stored["compare"] - stored["controller"], abs=1e-3)
    # The verdict follows the rule from the runs' own numbers (64 steps: either way is possible).
    last = [json.loads((sweep / str(k) / "metrics.json").read_text())["last_eval"] for k in (0, 1)]
    gain, spread = float(np.mean(last)) - stored["controller"], float(np.std(last))
    assert float(row["learned - controller"]) == pytest.approx(gain, abs=1e-3)
    assert float(row["seed spread (std)"]) == pytest.approx(spread, abs=1e-3)
    if loss <= 0.05:
        assert row["verdict"].startswith("no gain to find")
    else:
        beats = gain > spread and min(last) > stored["controller"]
        assert row["verdict"].startswith("beats") == beats and ("NOT" in row["verdict"]) == (not beats)
    # How large the learned correction is beside the noise it was learned under (medians over seeds).
    sizes = [json.loads((sweep / str(k) / "metrics.json").read_text()) for k in (0, 1)]
    rms = [m["last_eval_action_rms"] for m in sizes]
    assert all(0 < r < 1 for r in rms) and sizes[0]["exploration_std"] == pytest.approx(np.exp(-1.0), rel=1e-3)
    assert row["learned correction RMS / exploration std (box half-widths)"] == "{:.3f} / {:.3f}".format(
        np.median(rms), np.median([m["exploration_std"] for m in sizes]))
    assert (sweep / "residual_curves.png").stat().st_size > 0
    # The documented command prints the table again (baselines from the sweep's cache).
    again = job_process.run([sys.executable, "-m", "aslexp.reports.residual_report", str(sweep)], capture_output=True,
                           text=True, timeout=120, check=True)
    assert "| 52861 (snow) |" in again.stdout and "verdict" in again.stdout

    # Re-evaluated by job number (docs/imitation_upper_body.md), under the same protocol: the same
    # last evaluations, read as learned policies; no best-so-far; the curves show one point per run.
    reevaluated = tmp_path / "reevaluated"
    reevaluated.mkdir()
    shutil.copytree(sweep / "baselines", reevaluated / "baselines")  # the same protocol: cached
    run_job("imitate", "-m", "experiment=signs_free_residual", "motion='52861'", "seed=0,1", *TINY,
            f"resume={sweep}/${{hydra:job.num}}", f"hydra.sweep.dir={reevaluated}")
    with open(reevaluated / "residual_table.csv", newline="", encoding="utf-8") as fh:
        [same] = list(csv.DictReader(fh))
    assert same["learned, last evaluation"] == row["learned, last evaluation"]
    assert same["verdict"] == row["verdict"] and same["learned, best so far (secondary)"] == "n/a (re-evaluated)"
    assert (same["learned correction RMS / exploration std (box half-widths)"]
            == row["learned correction RMS / exploration std (box half-widths)"])
    assert (reevaluated / "residual_curves.png").stat().st_size > 0
    # ... and the table again from a shell, outside Hydra: each run's resume=${hydra:job.num} is its own.
    again = job_process.run([sys.executable, "-m", "aslexp.reports.residual_report", str(reevaluated)],
                           capture_output=True, text=True, timeout=120)
    assert again.returncode == 0 and "n/a (re-evaluated)" in again.stdout, again.stderr[-2000:]

    # Charging the drift in training (env.heading_shaping, env.offset_shaping) changes what PPO learns
    # from, not what is scored: the cached baselines still hold, and in two rollout workers the first
    # rollout (same seed, same policy before any update) is the unshaped run's, with the factor logged.
    runs = {}
    for name, charge in (("plain", []), ("shaped", ["env.heading_shaping=10", "env.offset_shaping=100"])):
        runs[name] = tmp_path / name
        runs[name].mkdir()
        shutil.copytree(sweep / "baselines", runs[name] / "baselines")
        ran = run_job("imitate", "-m", "experiment=signs_free_residual", "motion='52861'", "seed=0", *TINY,
                      "ppo.total_steps=128", "ppo.num_envs=2", *charge, f"hydra.sweep.dir={runs[name]}")
        assert "residual baselines 52861" not in ran.stdout + ran.stderr  # training-only keys: cache holds
    rows = {}
    for name, folder in runs.items():
        with open(folder / "0" / "progress.csv", newline="", encoding="utf-8") as fh:
            rows[name] = [r for r in csv.DictReader(fh) if r["train_reward"]]
    shaped_rows, plain_rows = rows["shaped"], rows["plain"]
    assert shaped_rows[0]["train_reward"] == plain_rows[0]["train_reward"]
    assert all(0 < float(r["train_drift"]) <= 1 for r in shaped_rows) and "train_drift" not in plain_rows[0]

    # What the exploration noise alone costs the controller in the run's training episodes (the
    # documented command, two short episodes per noise): no noise is the controller itself.
    cost = job_process.run([sys.executable, "-m", "aslexp.measure.noise_cost", str(sweep / "0"), "--betas", "0,2",
                           "--log-std", "-1.75", "--episodes", "2", "--steps", "12"],
                          capture_output=True, text=True, timeout=300)
    assert cost.returncode == 0, cost.stderr[-2000:]
    table = cost.stdout.splitlines()
    assert table[0].startswith("motion 52861, 2 training episodes") and len(table) == 6
    assert [line.split(" | ")[0] for line in table[3:]] == ["| none (the controller)", "| white", "| red"]
    assert "0.174 (log-std -1.75)" in table[4] and "3/3 noises" in cost.stderr
    quiet = [float(line.split(" | ")[2].split(" ± ")[0]) for line in table[3:]]
    assert all(0 < r <= 1 for r in quiet)


def _composed(experiment: str, *overrides: str) -> dict:
    """The imitate config of an experiment overlay (and overrides), Hydra's own section included, unresolved."""
    from hydra import compose, initialize_config_dir
    from omegaconf import OmegaConf

    from aslexp.paths import CONF_DIR

    with initialize_config_dir(config_dir=str(CONF_DIR), version_base="1.3"):
        composed = compose(config_name="imitate", overrides=[f"experiment={experiment}", *overrides],
                           return_hydra_config=True)
        return OmegaConf.to_container(composed, resolve=False)


def _job_envs(data_root, experiment: str, *overrides: str):
    """(the resolved job config, the training-env factory, the evaluation env) that aslexp imitate
    builds for an experiment overlay and overrides."""
    from aslexp.jobs._common import to_dict
    from aslexp.jobs.imitate import build_envs
    from hydra import compose, initialize_config_dir

    from aslexp.paths import CONF_DIR

    with initialize_config_dir(config_dir=str(CONF_DIR), version_base="1.3"):
        cfg = to_dict(compose(config_name="imitate", overrides=[f"experiment={experiment}", *overrides]))
    return (cfg, *build_envs(cfg, data_root))


def _drop_run_sections(cfg: dict) -> None:
    """Hydra's sections that name the run (its overrides, job and runtime): what two overlays that compose
    the same experiment still differ in."""
    for section in ("runtime", "overrides", "job"):
        cfg["hydra"].pop(section)


def test_signs_free_residual_composes_with_the_values_its_comments_claim():
    cfg = _composed("signs_free_residual")
    env, ppo, report = cfg["env"], cfg["ppo"], cfg["report"]["residual"]
    # The authors' code's controller (all stable PD, hands 50 / 0.5) and Table 6.4 Run 3's reward on the standing body.
    assert cfg["body"]["base"] == "free" and cfg["controller"]["mode"] == "stable_pd"
    assert cfg["controller"]["name"] == "upper_body_thesis_code"
    assert cfg["reward"]["terms"]["pose_body"]["scale"] == 2.0 and cfg["reward"]["terms"]["root"]["scale"] == 10.0
    # A residual on the reference one step ahead, normalised to +-0.2, 30 Hz, RSI, falls end episodes.
    assert env["action_mode"] == "residual" and env["normalize_actions"] is True and env["residual_range"] == 0.2
    assert (env["physics_hz"], env["control_hz"], env["episode_steps"]) == (240, 30, 300)
    assert env["reference_state_init"] is True and env["early_termination"]["fall"] is True
    assert ppo["log_std_init"] == -1.0 and ppo["target_kl"] is None and ppo["total_steps"] == 81920
    assert ppo["eval_steps"] == 300 and ppo["eval_episodes"] == 4 and ppo["num_envs"] == 2
    assert report["compare"] == {"body": {"base": "pinned"}} and report["min_loss"] == 0.05
    params = cfg["hydra"]["sweeper"]["params"]
    assert params["motion"] == "'00433','52861','69318','69546'" and params["seed"] == "0,1,2"
    assert cfg["hydra"]["callbacks"]["residual_summary"]["_target_"] == "aslexp.jobs.imitate.ResidualSummary"


def test_the_root_variant_changes_only_what_its_name_says():
    """experiment=archive/signs_free_residual_root: the base experiment plus two named changes, nothing else."""
    base, variant = _composed("signs_free_residual"), _composed("archive/signs_free_residual_root")
    assert variant["env"]["observe_reference_root"] is True and base["env"]["observe_reference_root"] is False
    assert variant["ppo"]["log_std_init"] == -1.75 and base["ppo"]["log_std_init"] == -1.0
    for cfg in (base, variant):
        cfg["env"].pop("observe_reference_root"), cfg["ppo"].pop("log_std_init")
        _drop_run_sections(cfg)
    assert variant == base  # same body, controller, reward, budget, report, sweep and callbacks


def test_the_anneal_variant_adds_only_its_two_schedules():
    """experiment=archive/signs_free_residual_anneal: the root variant plus a noise and a learning-rate schedule."""
    root, anneal = _composed("archive/signs_free_residual_root"), _composed("archive/signs_free_residual_anneal")
    assert (anneal["ppo"]["log_std_final"], anneal["ppo"]["learning_rate_final"]) == (-3.0, 0.0)
    assert (root["ppo"]["log_std_final"], root["ppo"]["learning_rate_final"]) == (None, None)
    for cfg in (root, anneal):
        cfg["ppo"].pop("log_std_final"), cfg["ppo"].pop("learning_rate_final")
        _drop_run_sections(cfg)
    assert anneal == root


def test_the_kl_variant_adds_only_a_trust_region_and_twice_the_budget():
    """experiment=archive/signs_free_residual_anneal_kl: the anneal variant, target_kl 0.02, 164 k steps."""
    anneal, kl = _composed("archive/signs_free_residual_anneal"), _composed("archive/signs_free_residual_anneal_kl")
    assert (anneal["ppo"]["target_kl"], anneal["ppo"]["total_steps"]) == (None, 81920)
    assert (kl["ppo"]["target_kl"], kl["ppo"]["total_steps"], kl["ppo"]["max_minutes"]) == (0.02, 163840, 30)
    for cfg in (anneal, kl):
        for key in ("target_kl", "total_steps", "max_minutes"):
            cfg["ppo"].pop(key)
        _drop_run_sections(cfg)
    assert kl == anneal


def test_the_batch_variant_changes_only_the_samples_per_update_at_twice_the_budget():
    """experiment=archive/signs_free_residual_anneal_batch: the anneal variant, 8192 steps and minibatches of
    1024 per update (the same 40 gradient steps per update), 164 k steps."""
    anneal, batch = _composed("archive/signs_free_residual_anneal"), _composed("archive/signs_free_residual_anneal_batch")
    keys = ("steps_per_rollout", "minibatch_size", "epochs", "total_steps", "max_minutes")
    assert [anneal["ppo"][k] for k in keys] == [2048, 256, 5, 81920, 12]
    assert [batch["ppo"][k] for k in keys] == [8192, 1024, 5, 163840, 30]
    for cfg in (anneal, batch):
        for key in keys:
            cfg["ppo"].pop(key)
        _drop_run_sections(cfg)
    assert batch == anneal


def test_the_quiet_variant_is_the_probe_s_overrides_of_the_anneal_variant():
    """experiment=archive/signs_free_residual_anneal_quiet composes exactly what the documented probe ran:
    the anneal variant with ppo.total_steps=163840 ppo.max_minutes=30 ppo.log_std_final=-4."""
    probe = _composed("archive/signs_free_residual_anneal", "ppo.total_steps=163840", "ppo.max_minutes=30",
                      "ppo.log_std_final=-4")
    quiet = _composed("archive/signs_free_residual_anneal_quiet")
    assert (quiet["ppo"]["log_std_init"], quiet["ppo"]["log_std_final"]) == (-1.75, -4.0)
    for cfg in (probe, quiet):
        _drop_run_sections(cfg)
    assert quiet == probe


def test_the_red_noise_variant_changes_only_the_colour_of_the_quiet_variant_s_noise():
    """experiment=archive/signs_free_residual_anneal_quiet_red: the quiet variant with ppo.noise_beta=2 over
    the 300-step episode (its horizon), nothing else; white noise (0) is every other experiment's."""
    quiet, red = _composed("archive/signs_free_residual_anneal_quiet"), _composed("archive/signs_free_residual_anneal_quiet_red")
    assert (quiet["ppo"]["noise_beta"], red["ppo"]["noise_beta"]) == (0.0, 2.0)
    assert red["ppo"]["noise_horizon"] == red["env"]["episode_steps"] == 300
    for cfg in (quiet, red):
        cfg["ppo"].pop("noise_beta")
        _drop_run_sections(cfg)
    assert red == quiet


def test_observe_reference_root_shows_the_turn_the_heading_frame_hides(data_root):
    from aslexp import quaternion

    _, make_train_env, eval_env = _job_envs(data_root, "signs_free_residual", "motion='00433'",
                                            "env.observe_reference_root=true")
    eval_env.close()
    env = make_train_env()
    plain_size = 2 + 13 * len(env.observed_links) + env.layout.action_size
    assert env.observation_space.shape == (plain_size + 7,)
    obs, _ = env.reset(options={"phase": 0.3})
    assert np.allclose(obs[-7:-4], 0.0, atol=1e-6)  # the body starts on the reference's root
    # Turn the simulated root by 20 degrees about the vertical: the links in the heading frame do not
    # change, the reference's root is seen turned by -20 degrees.
    position, rotation, velocity, spin = env.reference.root(env.time)
    turn = np.radians(20.0)
    env.sim.set_base(position, quaternion.multiply(np.array([np.cos(turn / 2), 0.0, np.sin(turn / 2), 0.0]),
                                                   rotation), velocity, spin)
    turned = env._observation(env.sim.link_states(links=env._state_links))
    assert np.allclose(turned[:-7], obs[:-7], atol=1e-4)  # what deepmimic's observation sees: nothing
    seen = turned[-4:]  # the reference's root in the simulated root's heading frame
    relative = quaternion.multiply(quaternion.conjugate(seen), obs[-4:])  # (w, x, y, z)
    assert np.degrees(2 * np.arctan2(relative[2], relative[0])) == pytest.approx(20.0, abs=0.1)
    env.close()


def test_the_heading_variant_changes_only_the_training_reward_of_the_quiet_variant():
    """experiment=archive/signs_free_residual_anneal_quiet_heading: the quiet variant with env.heading_shaping=10,
    nothing else; 0 (off) is every other experiment's."""
    quiet = _composed("archive/signs_free_residual_anneal_quiet")
    heading = _composed("archive/signs_free_residual_anneal_quiet_heading")
    assert (quiet["env"]["heading_shaping"], heading["env"]["heading_shaping"]) == (0.0, 10.0)
    assert quiet["env"]["offset_shaping"] == heading["env"]["offset_shaping"] == 0.0
    for cfg in (quiet, heading):
        cfg["env"].pop("heading_shaping")
        _drop_run_sections(cfg)
    assert heading == quiet


def test_drift_shaping_charges_the_turn_and_offset_in_training_envs_only(data_root):
    """env.heading_shaping, env.offset_shaping: the training env's reward is the reward config's times
    exp(-heading_shaping yaw^2 - offset_shaping |d|^2), yaw and d the simulated root's turn and horizontal
    offset against the reference's; the evaluation env scores the reward alone."""
    from aslexp import quaternion

    _, make_train_env, eval_env = _job_envs(data_root, "archive/signs_free_residual_anneal_quiet_heading",
                                            "motion='00433'", "env.offset_shaping=100")
    train_env = make_train_env()
    action = np.zeros(train_env.action_space.shape, np.float32)
    turn = np.radians(15.0)
    steps = []
    for env in (train_env, eval_env):
        env.reset(options={"phase": 0.3})
        position, rotation, velocity, spin = env.reference.root(env.time)  # turn the body by 15 degrees
        env.sim.set_base(position, quaternion.multiply(np.array([np.cos(turn / 2), 0.0, np.sin(turn / 2), 0.0]),
                                                       rotation), velocity, spin)
        steps.append(env.step(action))
        env.close()
    (_, shaped, _, _, info), (_, plain, _, _, eval_info) = steps
    yaw = quaternion.twist_angle(train_env.last_reference_state.root_rot, train_env.last_sim_state.root_rot, 1)
    assert abs(np.degrees(yaw)) == pytest.approx(15.0, abs=2.0)  # one step later, still turned
    offset = np.delete(train_env.last_sim_state.root_pos - train_env.last_reference_state.root_pos, 1)
    assert info["r_drift"] == pytest.approx(np.exp(-10.0 * yaw ** 2 - 100.0 * offset @ offset), rel=1e-9)
    assert "r_drift" not in eval_info
    # Same state, same action, same physics: the unshaped rewards agree, the shaped one carries the factor.
    assert shaped == pytest.approx(plain * info["r_drift"], rel=1e-6)
    assert shaped < 0.8 * plain
    means = train_env.pop_term_means()  # training logs: train_reward unshaped, train_drift the factor
    assert means["reward"] == pytest.approx(plain, rel=1e-6) and means["drift"] == info["r_drift"]


@pytest.mark.parametrize("name,value", [("heading_shaping", -1.0), ("offset_shaping", "a lot"),
                                        ("offset_shaping", float("nan"))])
def test_drift_shaping_scales_must_be_numbers_of_zero_or_more(name, value):
    from aslexp.envs.imitation import EnvSpec

    with pytest.raises(ValueError, match=f"env.{name}=.*: expected a number >= 0"):
        EnvSpec.parse({name: value})


def test_the_drift_variant_adds_only_the_offset_charge_to_the_heading_variant():
    heading = _composed("archive/signs_free_residual_anneal_quiet_heading")
    drift = _composed("archive/signs_free_residual_anneal_quiet_drift")
    assert (heading["env"]["offset_shaping"], drift["env"]["offset_shaping"]) == (0.0, 100.0)
    assert drift["env"]["heading_shaping"] == 10.0
    for cfg in (heading, drift):
        cfg["env"].pop("offset_shaping")
        _drop_run_sections(cfg)
    assert drift == heading


def test_the_328k_variant_is_the_probe_s_overrides_of_the_quiet_variant():
    """experiment=signs_free_residual_anneal_quiet_328k composes what the 69318 probe ran:
    the quiet variant with ppo.total_steps=327680 ppo.max_minutes=60, schedules stretched over it."""
    probe = _composed("archive/signs_free_residual_anneal_quiet", "ppo.total_steps=327680", "ppo.max_minutes=60")
    longer = _composed("signs_free_residual_anneal_quiet_328k")
    assert (longer["ppo"]["log_std_final"], longer["ppo"]["learning_rate_final"]) == (-4.0, 0.0)
    for cfg in (probe, longer):
        _drop_run_sections(cfg)
    assert longer == probe


def _upper_body_residual_env(data_root, **env_overrides):
    cfg, _, eval_env = _job_envs(data_root, "archive/signs_free_residual_anneal_quiet", "motion='69546'",
                                 *(f"env.{k}={v}" for k, v in env_overrides.items()))
    return cfg, eval_env


def test_a_smoothed_base_with_no_correction_is_the_smoothed_reference_baseline(data_root):
    """env.residual_base_smoothing: the correction is added to the low-pass filtered reference, so a
    zero correction drives what smoothed_reference_policy drives on the reference's own base, and the
    in-run baselines, measured within thesis_pd(), are the plain env's to the bit."""
    groups = ("chest", "neck", "shoulder", "elbow")
    _, plain = _upper_body_residual_env(data_root)
    _, smoothed = _upper_body_residual_env(data_root, residual_base_smoothing=0.6,
                                           residual_base_smoothing_groups="[chest,neck,shoulder,elbow]")
    zero = np.zeros(smoothed.action_space.shape, np.float32)
    on_base = evaluate(smoothed, lambda obs, env: zero, 45, phase=0.25)
    baseline = evaluate(plain, smoothed_reference_policy(0.6, groups), 45, phase=0.25)
    # The same targets; the baseline's pass through a float32 policy action (1e-8 rad apart).
    assert on_base.mean_reward == pytest.approx(baseline.mean_reward, abs=1e-6)
    assert on_base.terms == pytest.approx(baseline.terms, abs=1e-6)
    controller = evaluate(plain, reference_policy(1), 45, phase=0.25)
    assert abs(on_base.mean_reward - controller.mean_reward) > 1e-3  # the filter changes the targets
    # The in-run baselines (thesis_pd(): the base is the reference itself) are the controller's, to the bit.
    from aslexp.rl.evaluate import baselines
    assert baselines(smoothed, 45, (0.25, 0.5)) == baselines(plain, 45, (0.25, 0.5))
    with smoothed.thesis_pd():
        assert evaluate(smoothed, lambda obs, env: zero, 45, phase=0.25).mean_reward == controller.mean_reward
    # Only the chosen groups lag: after a few steps the base differs from the reference there alone.
    smoothed.reset(options={"phase": 0.25})
    for _ in range(5):
        smoothed.step(zero)
    lag = np.abs(smoothed.residual_base() - smoothed.reference_targets(1)) > 1e-9
    chosen = smoothed.joint_value_indices(groups)
    assert lag[chosen].any() and not lag[np.setdiff1d(np.arange(lag.size), chosen)].any()
    plain.close(), smoothed.close()


@pytest.mark.parametrize("values,message", [
    ({"action_mode": "residual", "residual_base_smoothing": 1.0}, r"env.residual_base_smoothing=1.0: expected a number in \[0, 1\)"),
    ({"action_mode": "residual", "residual_base_smoothing": "half"}, r"expected a number in \[0, 1\)"),
    ({"action_mode": "absolute", "residual_base_smoothing": 0.5}, "needs action_mode residual"),
])
def test_residual_base_smoothing_fails_clearly(values, message):
    from aslexp.envs.imitation import EnvSpec

    with pytest.raises(ValueError, match=message):
        EnvSpec.parse(values)


def test_residual_base_smoothing_groups_must_name_joints(motion_a):
    with pytest.raises(ValueError, match=r"env residual_base_smoothing_groups: no joint in groups \['toes'\]"):
        ImitationEnv(motion_a, env={**FIXED, "action_mode": "residual", "residual_base_smoothing": 0.5,
                                    "residual_base_smoothing_groups": ["toes"]})


def test_the_residual_baselines_ignore_a_smoothed_base(data_root, tmp_path):
    """The report's rows (controller, smoothed references, chance) are measured on the reference's own
    base for a smoothed-base variant too: the same rows, and the same cache entry."""
    from aslexp.measure.residual import residual_baselines

    small = {"eval_steps": 15, "eval_episodes": 2}
    settings = {"smoothing": [0.6], "smoothing_groups": ["chest", "neck", "shoulder", "elbow"],
                "random_corrections": {"count": 1, "rms": 0.04, "seed": 0}}
    rows = []
    for extra in ({}, {"residual_base_smoothing": 0.6,
                       "residual_base_smoothing_groups": "[chest,neck,shoulder,elbow]"}):
        cfg, env = _upper_body_residual_env(data_root, **extra)
        env.close()
        cfg["ppo"].update(small)
        cfg["report"]["residual"] = settings
        rows.append(residual_baselines(cfg, tmp_path / "baselines.json"))
        if not extra:
            written = (tmp_path / "baselines.json").stat().st_mtime_ns
    assert rows[0] == rows[1]
    assert (tmp_path / "baselines.json").stat().st_mtime_ns == written  # a cache hit: nothing measured again


def test_the_smoothed_base_variant_changes_only_the_residual_s_base():
    quiet = _composed("archive/signs_free_residual_anneal_quiet")
    smoothed = _composed("archive/signs_free_residual_anneal_quiet_smoothed_base")
    assert (quiet["env"]["residual_base_smoothing"], smoothed["env"]["residual_base_smoothing"]) == (0.0, 0.6)
    assert smoothed["env"]["residual_base_smoothing_groups"] == smoothed["report"]["residual"]["smoothing_groups"]
    assert 0.6 in smoothed["report"]["residual"]["smoothing"]  # its zero correction is a row of the table
    for cfg in (quiet, smoothed):
        cfg["env"].pop("residual_base_smoothing"), cfg["env"].pop("residual_base_smoothing_groups")
        _drop_run_sections(cfg)
    assert smoothed == quiet
