"""The "thesis" PPO configs and sweep files hold exactly the thesis' values (tests/imitation/
thesis_values.py, itself checked against THESIS.md)."""

from __future__ import annotations

from pathlib import Path

import yaml
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

from aslexp.compose import resolve_group
from aslexp.paths import CONF_DIR
from hydra_plugins.aslexp_optuna_sweeper._space import parse_search_space

from . import thesis_values as T

SWEEPS = CONF_DIR.parent / "sweeps"


def per_env_steps(ppo: dict, authors_envs: int) -> float:
    """SB3's n_steps (per environment): aslexp's steps_per_rollout is the batch of one update, all
    ``num_envs`` environments together."""
    assert ppo["num_envs"] == authors_envs
    return ppo["steps_per_rollout"] / ppo["num_envs"]


def test_hand_thesis_is_table_d1s_best_row():
    ppo = resolve_group("ppo", "hand_thesis")
    got = {"batch_size": ppo["minibatch_size"], "gamma": ppo["gamma"], "learning_rate": ppo["learning_rate"],
           "log_std_init": ppo["log_std_init"], "n_epochs": ppo["epochs"],
           "n_steps": per_env_steps(ppo, T.AUTHORS_ENVS_HAND), "ortho_init": ppo["ortho_init"],
           "weight_decay": ppo["weight_decay"]}
    assert got == T.TABLE_D1_BEST
    assert ppo["hidden_sizes"] == [1024, 1024]  # THESIS.md 3.1: 2 hidden layers x 1024


def test_upper_body_runs_are_tables_6_3_and_6_6():
    for name, table in (("upper_body_run1", T.TABLE_6_3), ("upper_body_run2", T.TABLE_6_6)):
        ppo = resolve_group("ppo", name)
        got = {"hidden": ppo["hidden_sizes"], "learning_rate": ppo["learning_rate"],
               "n_steps": per_env_steps(ppo, T.AUTHORS_ENVS_UPPER_BODY), "batch_size": ppo["minibatch_size"],
               "log_std": ppo["log_std_init"], "gamma": ppo["gamma"], "n_epochs": ppo["epochs"]}
        assert got == table, name
        # The authors' script where the text is silent (THESIS.md 10.1).
        assert (ppo["value_coef"], ppo["max_grad_norm"], ppo["target_kl"], ppo["gae_lambda"],
                ppo["entropy_coef"], ppo["clip_epsilon"]) == (5.0, 100.0, 0.05, 0.95, 0.0, 0.2), name


def space(sweep: str) -> dict[str, list]:
    """The sweep's choices as plain lists, read from the composed config as the sweeper reads them."""
    with initialize_config_dir(config_dir=str(CONF_DIR), version_base="1.3"):
        cfg = compose(config_name="imitate", overrides=[f"+sweeps={sweep}"], return_hydra_config=True)
    params = OmegaConf.to_container(cfg.hydra.sweeper.params, resolve=False)
    return {k: list(d.choices) for k, d in parse_search_space(params, []).distributions.items()}


def test_ppo_hand_thesis_is_table_5_3():
    got = space("ppo_hand_thesis")
    assert got == {
        "ppo.learning_rate": T.TABLE_5_3["learning_rate"],
        "ppo.steps_per_rollout": [T.AUTHORS_ENVS_HAND * n for n in T.TABLE_5_3["n_steps"]],
        "ppo.weight_decay": T.TABLE_5_3["weight_decay"], "ppo.minibatch_size": T.TABLE_5_3["batch_size"],
        "ppo.ortho_init": T.TABLE_5_3["ortho_init"], "ppo.gamma": T.TABLE_5_3["gamma"],
        "ppo.log_std_init": T.TABLE_5_3["log_std_init"], "ppo.epochs": T.TABLE_5_3["n_epochs"]}
    assert yaml.safe_load((SWEEPS / "ppo_hand_thesis.yaml").read_text())["hydra"]["sweeper"]["n_trials"] == 50


def test_ppo_upper_body_thesis_is_table_6_2():
    assert space("ppo_upper_body_thesis") == {
        "ppo.learning_rate": T.TABLE_6_2["learning_rate"],
        "ppo.steps_per_rollout": [T.AUTHORS_ENVS_UPPER_BODY * n for n in T.TABLE_6_2["n_steps"]],
        "ppo.minibatch_size": T.TABLE_6_2["batch_size"], "ppo.log_std_init": T.TABLE_6_2["log_std"],
        "ppo.gamma": T.TABLE_6_2["gamma"], "ppo.epochs": T.TABLE_6_2["n_epochs"]}


def test_kfactors_upper_body_thesis_is_the_16_pair_grid():
    got = space("kfactors_upper_body_thesis")
    assert got == {"reward.terms.pose_hands.scale": T.K_GRID["k_p,h"],
                   "reward.terms.velocity_hands.scale": T.K_GRID["k_v,h"]}
    text = yaml.safe_load((SWEEPS / "kfactors_upper_body_thesis.yaml").read_text())
    assert text["hydra"]["sweeper"]["n_trials"] == 16 and text["ppo"]["total_steps"] == 25_000_000


def test_no_config_claims_to_be_thesis_without_being_tested():
    """Every imitation conf/ppo, conf/reward and sweeps file named *thesis* is one of those tested
    here (the recognition sweeps classifier_*_thesis_ch3|ch4 are tested in tests/recognition)."""
    named = {p.relative_to(CONF_DIR.parent).as_posix() for d in (CONF_DIR / "ppo", CONF_DIR / "reward", SWEEPS)
             for p in Path(d).glob("*thesis*.yaml") if not p.name.startswith("classifier_")}
    assert named == {"conf/ppo/hand_thesis.yaml", "conf/reward/hand_thesis.yaml", "conf/reward/upper_body_thesis.yaml",
                     "sweeps/ppo_hand_thesis.yaml", "sweeps/ppo_upper_body_thesis.yaml",
                     "sweeps/kfactors_upper_body_thesis.yaml"}


def _composed(experiment: str) -> dict:
    with initialize_config_dir(config_dir=str(CONF_DIR), version_base="1.3"):
        return OmegaConf.to_container(compose(config_name="imitate", overrides=[f"experiment={experiment}"]),
                                      resolve=True)


def test_signs_thesis_runs_compose_with_the_texts_hand_gains():
    """Table 6.7's overlays drive the body with DeepMimic's gains under stable PD and the hands' finger
    joints with the chapter-5 hand's position control 0.22 / 0.87 (THESIS.md 4.9, the text; 10); the
    authors' code's controller (hands 50 / 0.5 under stable PD, 10.1) is a labelled baseline row."""
    for experiment in ("signs_thesis_run1", "signs_thesis_run2"):
        cfg = _composed(experiment)
        controller = cfg["controller"]
        assert controller["name"] == "upper_body_thesis" and controller["mode"] == "stable_pd"
        fingers = controller["groups"]["fingers"]
        assert (fingers["mode"], fingers["kp"], fingers["kd"], fingers["max_force"]) == (
            "position", *T.HAND_GAINS_TEXT, 100.0)
        for group in ("chest", "neck", "shoulder", "elbow", "wrist"):
            gains = controller["groups"][group]
            assert gains.get("mode") is None and (gains["kp"], gains["kd"]) == T.UPPER_BODY_GAINS[group], group
        assert cfg["body"]["base"] == "free" and cfg["env"]["control_hz"] == 240
        rows = {row["label"]: row for row in cfg["report"]["baselines"]}
        thesis = [r for r in rows.values() if r["controller"] == "upper_body_thesis"]
        code = [r for r in rows.values() if r["controller"] == "upper_body_thesis_code"]
        assert thesis and all(label.startswith("thesis PD") for label in (r["label"] for r in thesis))
        assert code and all(r["label"].startswith("authors' code: stable PD, hands 50/0.5") for r in code)
        assert not any("authors' stable PD" in label for label in rows)
    code = resolve_group("controller", "upper_body_thesis_code")
    assert code["mode"] == "stable_pd" and all(g.get("mode") is None for g in code["groups"].values())
    assert {g: (v["kp"], v["kd"]) for g, v in code["groups"].items() if g != "default"} == T.UPPER_BODY_GAINS
