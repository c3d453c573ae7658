"""A training pool of real signs, folded by gloss (train_motions=wlasl_signs, experiment=signs_unseen), on a
real slice of the shared WLASL clips: eight MediaPipe Pose arrays extracted here, four glosses with two
clips each, one of them (70033, "coffee") marked implausible by the extraction (its arms out of view)."""

from __future__ import annotations

import contextlib
import dataclasses
import io
import json
import os
import sys
from pathlib import Path

import numpy as np
import pytest
import job_process

from aslexp.compose import compose, resolve_group
from aslexp.envs.assembly import ImitationSetup
from aslexp.envs.batched import BatchedImitationEnv
from aslexp.envs.motion_pool import TrainMotionsSpec, sign_fold, training_motions
from aslexp.envs.sign_folds import gloss_folds
from aslexp.errors import ConfigError, DataError

# again, cookie, ready: two plausible clips each; coffee: one plausible, one (70033) out of view
SLICE = {"01457": "again", "01467": "again", "13169": "cookie", "13180": "cookie", "46287": "ready",
         "46302": "ready", "11552": "coffee", "70033": "coffee"}
THESIS = {"00433": "above", "52861": "snow", "69318": "father", "69546": "yes"}


@pytest.fixture(scope="module")
def sign_slice(data_root, tmp_path_factory) -> Path:
    from aslexp.pose.extract_cli import extract_main

    arrays = data_root / "keypoints" / "wlasl-mediapipe-pose"
    wlasl = data_root / "wlasl" / "WLASL_v0.3.json"
    if not arrays.is_dir() or not wlasl.is_file():
        pytest.skip(f"the shared WLASL pose arrays or {wlasl} are not under {data_root}")
    out = tmp_path_factory.mktemp("signs")
    with contextlib.redirect_stdout(io.StringIO()):
        code = extract_main([*(str(arrays / f"{v}.npy") for v in SLICE), "--motions", "--out", str(out),
                             "--wlasl", str(wlasl), "--quiet"])
    assert code == 0
    return out


def _spec(folder: Path, **changes) -> TrainMotionsSpec:
    values = {**resolve_group("train_motions", "wlasl_signs"), "folder": str(folder), "folds": 2, **changes}
    return TrainMotionsSpec.parse(values)


def test_the_thesis_signs_glosses_are_wlasls(data_root):
    wlasl = data_root / "wlasl" / "WLASL_v0.3.json"
    if not wlasl.is_file():
        pytest.skip(f"{wlasl} not found")
    glosses = {i["video_id"]: entry["gloss"] for entry in json.loads(wlasl.read_text()) for i in entry["instances"]}
    spec = TrainMotionsSpec.parse(resolve_group("train_motions", "wlasl_signs"))
    assert spec.thesis_signs == {v: glosses[v] for v in THESIS} == THESIS
    assert spec.include_thesis_signs and spec.fold is None


def test_no_fold_trains_on_a_gloss_it_tests_and_the_run_motion_picks_its_fold(sign_slice, data_root):
    spec = _spec(sign_slice)
    glosses = set(SLICE.values()) | set(THESIS.values())
    tested = []
    for k in range(spec.folds):
        fold = sign_fold(dataclasses.replace(spec, fold=k), data_root)
        trained = {SLICE.get(name) or THESIS[name] for name in fold.summary()["motions"]}
        assert trained and not trained & set(fold.test_glosses)
        assert trained | set(fold.test_glosses) == glosses  # every gloss is trained or tested
        tested += fold.test_glosses
    assert sorted(tested) == sorted(glosses)  # each gloss tested in exactly one fold
    # the assignment is the seed's and the gloss list's alone: recorded, and the same again
    assert fold.assignment == gloss_folds(sorted(glosses), 2, spec.seed)
    assert gloss_folds(list(reversed(sorted(glosses))), 2, spec.seed) == fold.assignment
    assert any(gloss_folds(glosses, 2, seed) != fold.assignment for seed in range(1, 6))
    # fold null: the fold that tests the run's motion's gloss; the clip and every clip of its gloss held out
    for evaluated, gloss in ((data_root / "motions" / "upper_body" / "00433.txt", "above"),
                             (sign_slice / "motions" / "upper_body" / "01457.txt", "again")):
        fold = sign_fold(spec, data_root, str(evaluated))
        assert fold.held_out == evaluated.stem and fold.held_out_gloss == gloss and gloss in fold.test_glosses
        assert fold.fold == fold.assignment[gloss]
        assert not {c.name for c in fold.train} & {v for v, g in {**SLICE, **THESIS}.items() if g == gloss}
    with pytest.raises(ConfigError, match="train_motions.fold=null"):
        sign_fold(dataclasses.replace(spec, include_thesis_signs=False), data_root, "motions/upper_body/00433.txt")
    with pytest.raises(ConfigError, match="train_motions.folds=9: expected 2 to 8"):
        sign_fold(dataclasses.replace(spec, folds=9, fold=0), data_root)


def test_a_folder_that_is_no_extraction_is_one_line(sign_slice, data_root, tmp_path):
    with pytest.raises(ConfigError, match=r"train_motions.folder=\S*nowhere: no such folder"):
        sign_fold(_spec(tmp_path / "nowhere"), data_root)
    with pytest.raises(DataError, match="no motions/reports/ in it"):
        sign_fold(_spec(tmp_path), data_root)
    reports = tmp_path / "motions" / "reports"
    reports.mkdir(parents=True)
    report = json.loads((sign_slice / "motions" / "reports" / "01457.json").read_text())
    del report["pose_array"]["gloss"]
    (reports / "01457.json").write_text(json.dumps(report))
    with pytest.raises(DataError, match=r"01457.json: pose_array.gloss: expected the clip's gloss"):
        sign_fold(_spec(tmp_path), data_root)


def test_implausible_motions_are_left_out_and_counted(sign_slice, data_root):
    report = json.loads((sign_slice / "motions" / "reports" / "70033.json").read_text())
    assert report["upper_body"]["plausibility"]["plausible"] is False  # the extraction's own verdict
    spec = _spec(sign_slice, include_thesis_signs=False)
    folds = gloss_folds(set(SLICE.values()), spec.folds, spec.seed)
    evaluated = next(v for v, g in SLICE.items() if folds[g] != folds["coffee"])  # a fold that trains on coffee
    motion = sign_slice / "motions" / "upper_body" / f"{evaluated}.txt"
    setup = ImitationSetup.from_groups(motion, body="upper_body", data_root=data_root)
    pool = training_motions(spec, setup, str(motion))
    signs = pool.summary()["signs"]
    assert "coffee" not in signs["test_glosses"] and SLICE[evaluated] in signs["test_glosses"]
    assert signs["implausible_left_out"] == {"count": 1, "motions": {"70033": ["out_of_view"]}}
    assert signs["implausible_in_folder"] == 1 and "70033" not in signs["motions"] and "11552" in signs["motions"]
    assert pool.summary()["count"] == len(pool.motions) == len(signs["motions"]) and pool.held_out == evaluated


def test_a_batch_of_signs_reads_each_rows_own_motion_ahead(sign_slice, data_root):
    """The pool mixes lengths and frame steps (the extracted clips at 25 fps, the thesis' 69318 at
    0.03 s); each row observes its own motion's reference one control step ahead (the last values)."""
    cfg = compose("imitate", ["experiment=signs_unseen", "motion='00433'", f"train_motions.folder={sign_slice}",
                              "train_motions.folds=2", "train_motions.seed=2", f"data_root={data_root}"])
    setup = ImitationSetup.from_config(cfg, data_root)
    env = setup.env
    assert list(env.observe_future) == [1] and not (env.observe_future_velocities or env.observe_joints
                                                    or env.observe_reference_root)  # the frame ahead comes last
    from aslexp.jobs._imitation import training_pool

    pool = training_pool(cfg, setup)
    assert "69318" in pool.signs["thesis_signs"] and len({round(float(m.dt[0]), 6) for m in pool.motions}) == 2
    batch = BatchedImitationEnv.from_setup(16, setup, shape_reward=True, motions=pool.motions)
    durations = batch.pool.durations
    assert len(pool.motions) == 6 and len(set(np.round(durations, 6))) == 5  # lengths of 1.56 s to 4.16 s
    obs, _ = batch.reset(seed=list(range(16)))
    actions = np.zeros((16, batch.single_action_space.shape[0]), dtype=np.float32)
    for _ in range(3):
        obs, *_ = batch.step(actions)
    assert len(set(batch.clip.tolist())) >= 3
    dt = 1.0 / env.control_hz
    for row in range(16):
        own = int(batch.clip[row])
        assert 0.0 <= batch.time[row] <= durations[own] + 3 * dt
        ahead = [r.joints_many(np.array([batch.time[row] + dt]))[0] for r in batch.pool.references]
        seen = obs[row, -len(ahead[own]):]
        np.testing.assert_allclose(seen, ahead[own], atol=1e-5)
        assert not any(np.allclose(seen, other, atol=1e-5) for i, other in enumerate(ahead) if i != own)
    batch.close()


def test_the_tracking_error_variant_sees_each_rows_frame_ahead_minus_its_joints(sign_slice, data_root):
    """experiment=signs_unseen_tracking_error: the frame ahead is seen as that row's reference minus the
    body's joints now (the same quantity whichever motion a row follows), the joints follow, no phase."""
    overrides = ["motion='00433'", f"train_motions.folder={sign_slice}", "train_motions.folds=2",
                 "train_motions.seed=2", f"data_root={data_root}"]
    variant = ImitationSetup.from_config(compose("imitate", ["experiment=signs_unseen_tracking_error", *overrides]),
                                         data_root)
    plain = ImitationSetup.from_config(compose("imitate", ["experiment=signs_unseen", *overrides]), data_root)
    assert variant.env.observe_future_as == "error" and not variant.env.observe_phase and variant.env.observe_joints
    from aslexp.jobs._imitation import training_pool

    pool = training_pool(compose("imitate", ["experiment=signs_unseen_tracking_error", *overrides]), variant)
    batch = BatchedImitationEnv.from_setup(8, variant, shape_reward=True, motions=pool.motions)
    sizes = [BatchedImitationEnv.from_setup(1, s, motions=pool.motions) for s in (variant, plain)]
    actions = np.zeros((8, batch.single_action_space.shape[0]), dtype=np.float32)
    batch.reset(seed=list(range(8)))
    for _ in range(3):
        obs, *_ = batch.step(actions)
    q, qd = batch.body.joints(batch.states)
    size, velocity = q.shape[1], qd.shape[1]
    # no phase (-1), the joints and their velocities (+)
    assert sizes[0].single_observation_space.shape[0] == sizes[1].single_observation_space.shape[0] - 1 + size + velocity
    dt = 1.0 / variant.env.control_hz
    for row in range(8):
        reference = batch.pool.references[int(batch.clip[row])]
        ahead = reference.joints_many(np.array([batch.time[row] + dt]))[0]
        np.testing.assert_allclose(obs[row, -(2 * size + velocity):-(size + velocity)], ahead - q[row], atol=1e-5)
        np.testing.assert_allclose(obs[row, -(size + velocity):-velocity], q[row], atol=1e-5)
    assert np.abs(obs[:, -(2 * size + velocity):-(size + velocity)]).max() > 0
    for env in (batch, *sizes):
        env.close()


def _imitate(tmp_path: Path, data_root: Path, run: str, *overrides: str, experiment: str = "signs_unseen") -> dict:
    """A tiny `aslexp imitate experiment=...` run; ``overrides`` win over the tiny budget."""
    env = {**os.environ, "ASLEXP_DATA_ROOT": str(data_root), "MPLBACKEND": "Agg"}
    tiny = ["ppo.total_steps=256", "ppo.num_envs=8", "ppo.steps_per_rollout=128", "ppo.minibatch_size=64",
            "ppo.eval_interval=256", "ppo.eval_steps=30", "ppo.eval_episodes=1", "ppo.hidden_sizes=[16,16]",
            "plots=false", "render.gif=false", "render.mp4=false"]
    proc = job_process.run([sys.executable, "-m", "aslexp.cli", "imitate", f"experiment={experiment}", *tiny,
                            *overrides, f"hydra.run.dir={tmp_path / run}"], capture_output=True, text=True, timeout=600,
                           env=env)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert json.loads((tmp_path / run / "run.json").read_text())["status"] == "completed"
    return json.loads((tmp_path / run / "metrics.json").read_text())


def test_the_overlay_scores_a_held_out_sign_zero_shot(sign_slice, data_root, tmp_path):
    """experiment=signs_unseen, tiny: on the thesis' 00433 (no source keypoints: no `signing`) and on an
    extracted clip held out of its fold, which is also scored against the signer."""
    folder = [f"train_motions.folder={sign_slice}", "train_motions.folds=2", "train_motions.seed=2"]
    thesis = _imitate(tmp_path, data_root, "above", "motion='00433'", *folder)
    signs = thesis["train_motions"]["signs"]
    assert thesis["motion"] == "00433" and thesis["train_motions"]["held_out"] == "00433"
    assert signs["held_out_gloss"] == "above" and "00433" not in signs["motions"]
    assert thesis["train_motions"]["count"] == len(signs["motions"]) > 0 and 0.0 < thesis["last_eval"] <= 1.0
    assert thesis["steps"] == 256 and "signing" not in thesis
    assert signs["implausible_left_out"] == {"count": 1, "motions": {"70033": ["out_of_view"]}}

    clip = sign_slice / "motions" / "upper_body" / "01457.txt"
    held = _imitate(tmp_path, data_root, "again", f"motion.file={clip}", "motion.name=01457", *folder)
    signs = held["train_motions"]["signs"]
    assert signs["held_out"] == "01457" and "again" in signs["test_glosses"]
    assert not {"01457", "01467"} & set(signs["motions"]) and {"00433", "13169"} <= set(signs["motions"])
    assert set(held["signing"]["stages"]) >= {"reference", "policy", "controller"}


def _signing(tmp_path: Path, data_root: Path, run: str, *overrides: str) -> dict:
    """`aslexp signing` on the slice with tiny read-back models (3 gloss folds of nine glosses, two
    properties, logistic regression; cached under ``tmp_path``)."""
    read_back = [f"model_cache={tmp_path / 'models'}", "folds=3",
                 "glosses=[again,coffee,cookie,ready,can,eat,table,time,need]",
                 f"overrides=['data.num_frames=24','cache_dir={tmp_path / 'datasets'}']",
                 "lookup.overrides=['classifier=logreg','retrieval.properties=[sign_type,major_location]']"]
    env = {**os.environ, "ASLEXP_DATA_ROOT": str(data_root), "MPLBACKEND": "Agg"}
    proc = job_process.run([sys.executable, "-m", "aslexp.cli", "signing", *overrides,
                            f"signing.read_back.overrides=[{','.join(json.dumps(o) for o in read_back)}]",
                            f"hydra.run.dir={tmp_path / run}"], capture_output=True, text=True, timeout=600, env=env)
    assert proc.returncode == 0, proc.stderr[-3000:]
    folder = tmp_path / run
    assert json.loads((folder / "run.json").read_text())["status"] == "completed"
    records = [json.loads(line) for line in (folder / "clips.jsonl").read_text().splitlines()]
    return {"records": records, "table": json.loads((folder / "signing.json").read_text()), "folder": folder,
            "log": proc.stderr}


def test_the_signing_table_scores_every_clip_against_the_person_and_reads_it_back(sign_slice, data_root, tmp_path):
    """`aslexp signing` on the slice: every plausible clip performed (the retargeted reference, the
    controller alone), scored against its source keypoints and read back beside the person's own
    clip by a fold model that never saw its gloss; the table, its figure, and a resumed run that
    scores nothing again."""
    first = _signing(tmp_path, data_root, "table", f"signing.motions={sign_slice}")
    records, out = first["records"], first["table"]
    assert [r["motion"] for r in records] == sorted(set(SLICE) - {"70033"})  # 70033 is implausible
    assert out["left_out"] == [{"motion": "70033", "why": "implausible: out_of_view"}]
    for record in records:
        assert record["gloss"] == SLICE[record["motion"]]
        assert set(record["stages"]) == {"reference", "controller"}
        assert all(0.0 <= record["stages"][s]["body"]["dtw_mje"] < 1.0 for s in record["stages"])
        assert 0.0 < record["rewards"]["controller"] <= 1.0
        read = record["read_back"]
        assert set(read["stages"]) == {"source", "reference", "controller"}
        for stage in read["stages"].values():
            assert set(stage["properties"]) == {"sign_type", "major_location"}
            assert 1.0 <= stage["lexicon_rank"] <= stage["lexicon_size"]
        assert f"held out {record['gloss']!r}" in read["fold_note"]  # the fold that read it never saw its gloss
    table = out["table"]
    assert table["clips"] == 7 and table["glosses"] == 4 and table["stages"] == ["reference", "controller"]
    assert set(table["read_back"]) == {"source", "reference", "controller"}
    assert set(table["targets"]["controller"]) == {"sign_type agreement", "major_location agreement",
                                                   "lookup median rank", "body keypoint error"}
    markdown = (first["folder"] / "signing.md").read_text()
    assert "| lookup median rank |" in markdown and "body keypoint error" in markdown
    from PIL import Image

    with Image.open(first["folder"] / "signing.png") as image:
        assert image.size[0] > 3 * image.size[1] / 2  # three panels side by side

    again = _signing(tmp_path, data_root, "resumed", f"signing.motions={sign_slice}", f"resume={first['folder']}")
    assert all(r["reused_from"] == str(first["folder"]) for r in again["records"])
    assert again["table"]["table"]["keypoint_error"] == table["keypoint_error"]


def test_validation_glosses_neither_train_nor_test(sign_slice, data_root):
    """validation_motions: the next fold's glosses leave the pool; that many of their plausible motions,
    one gloss after another, validate."""
    spec = _spec(sign_slice, folds=4, validation_motions=3)
    glosses = {**SLICE, **THESIS}
    for k in range(spec.folds):
        fold = sign_fold(dataclasses.replace(spec, fold=k), data_root)
        trained = {glosses[c.name] for c in fold.train}
        held = set(fold.validation_glosses)
        assert held and held == {g for g, f in fold.assignment.items() if f == (k + 1) % 4}
        assert not held & trained and not held & set(fold.test_glosses)
        assert trained | held | set(fold.test_glosses) == set(glosses.values())
        chosen = [c.name for c in fold.validation]
        assert 1 <= len(chosen) <= 3 and {glosses[n] for n in chosen} <= held and "70033" not in chosen
        # one gloss after another: two validation glosses give two, never one gloss's two clips first
        assert len({glosses[n] for n in chosen}) == min(len(held), len(chosen))
        summary = fold.summary()
        assert summary["validation_motions"] == chosen and summary["validation_glosses"] == sorted(held)
    assert "validation_motions" not in sign_fold(dataclasses.replace(spec, validation_motions=0, fold=0),
                                                 data_root).summary()


def test_the_thesis_signs_can_validate_and_then_neither_train_nor_test(sign_slice, data_root):
    """validation_from=thesis_signs (experiment=signs_unseen_arms_thesis_validated): the thesis' signs
    outside the test glosses validate, by name; their glosses leave the pool, the next fold's train."""
    overlay = compose("imitate", ["experiment=signs_unseen_arms_thesis_validated"])["train_motions"]
    assert (overlay["validation_from"], overlay["validation_motions"]) == ("thesis_signs", 3)
    # seed 3 deals above and yes into one fold, snow and father into the other
    spec = _spec(sign_slice, validation_from="thesis_signs", validation_motions=3, seed=3)
    glosses = {**SLICE, **THESIS}
    for held_out in THESIS:
        fold = sign_fold(spec, data_root, str(data_root / "motions" / "upper_body" / f"{held_out}.txt"))
        chosen = [c.name for c in fold.validation]
        assert chosen == sorted(n for n in THESIS if n != held_out and glosses[n] not in fold.test_glosses)
        assert len(chosen) == 2 and fold.summary()["validation_motions"] == chosen
        trained = {glosses[c.name] for c in fold.train}
        assert not set(fold.validation_glosses) & trained and glosses[held_out] in fold.test_glosses
        assert trained | set(fold.validation_glosses) | set(fold.test_glosses) == set(glosses.values())
    for unable in (dataclasses.replace(spec, include_thesis_signs=False, fold=0),  # no thesis sign at all
                   dataclasses.replace(spec, seed=0, fold=1)):  # seed 0: all four in fold 1, tested
        with pytest.raises(ConfigError, match="validation_from=thesis_signs: no thesis sign outside"):
            sign_fold(unable, data_root)


def test_the_validated_variant_ends_on_the_policy_its_validation_chose(sign_slice, data_root, tmp_path):
    """experiment=signs_unseen_validated, tiny: the untrained policy and every evaluation validated on
    the next fold's motions; the best-validated checkpoint is the run's last row, its headline and the
    policy `policy=RUN_DIR` performs."""
    import csv

    import torch

    folder = [f"train_motions.folder={sign_slice}", "train_motions.folds=4", "train_motions.seed=2",
              "train_motions.validation_motions=2", "ppo.total_steps=768", "ppo.eval_interval=256", "ppo.learning_rate=0.01"]
    metrics = _imitate(tmp_path, data_root, "validated", "motion='00433'", *folder,
                       experiment="signs_unseen_validated")
    run = tmp_path / "validated"
    rows = [r for r in csv.DictReader((run / "progress.csv").open()) if r["eval_reward"]]
    validated = [(int(r["step"]), float(r["validation_reward"])) for r in rows[:-1]]
    assert [s for s, _ in validated] == [0, 256, 512, 768]  # the untrained policy is a candidate
    best_step = max(validated, key=lambda sv: sv[1])[0]
    selected = metrics["selected"]
    assert selected["step"] == best_step == int(rows[-1]["selected_step"])
    assert selected["validation_motions"] == metrics["train_motions"]["signs"]["validation_motions"]
    assert len(selected["validation_motions"]) == 2
    assert metrics["last_eval"] == float(rows[-1]["eval_reward"]) and metrics["steps"] == 768
    assert selected["last_trained_eval"] == float(rows[-2]["eval_reward"])
    # the last row evaluates the chosen weights: deterministic episodes score what they scored then
    assert float(rows[-1]["eval_reward"]) == float(next(r for r in rows if int(r["step"]) == best_step)["eval_reward"])
    saved = torch.load(run / "checkpoints" / "selected.pt", weights_only=False)
    assert saved["steps"] == best_step
    from aslexp.jobs.performing import run_policy_checkpoint

    assert run_policy_checkpoint(run) == run / "checkpoints" / "selected.pt"


def test_validation_episodes_in_one_batch_score_as_single_evaluations(sign_slice, data_root):
    """evaluate_rows (every validation motion and start phase a row of one batch) gives each episode
    the reward the single environment's evaluation gives it, a correction applied and a fall included."""
    from aslexp.envs.imitation import ImitationEnv
    from aslexp.rl.evaluate import evaluate_phases, evaluate_rows

    cfg = compose("imitate", ["experiment=signs_unseen_validated", "motion='00433'", f"data_root={data_root}"])
    setup = ImitationSetup.from_config(cfg, data_root).merged(env={"early_termination": {"min_reward": None},
                                                                     "episode_steps": 150})
    names = ["01457", "13169", "46287"]
    motions = [setup.load_motion(sign_slice / "motions" / "upper_body" / f"{n}.txt") for n in names]
    phases = np.array([0.0, 0.5])
    batch = BatchedImitationEnv.from_setup(len(names) * 2, setup, motions=motions)
    size = batch.single_action_space.shape[0]
    push = np.linspace(-1.0, 1.0, size)  # a constant correction at the box's edges: 46287's body falls

    rewards, blew_up = evaluate_rows(batch, lambda obs: np.tile(push, (len(obs), 1)), 150,
                                     np.repeat(np.arange(3), 2), np.tile(phases, 3))
    single, ended = [], 0
    for motion in motions:
        env = ImitationEnv.from_setup(dataclasses.replace(setup, motion=motion))
        summary = evaluate_phases(env, lambda obs, env: push, 150, tuple(phases))
        single, ended = single + summary.rewards, ended + summary.ended_early
        env.close()
    np.testing.assert_allclose(rewards, single, atol=1e-6)
    assert ended == 2 and not blew_up.any() and len(set(np.round(rewards, 4))) == 6
    batch.close()


def test_an_arms_policy_on_its_held_out_fold_is_a_row_of_the_leave_glosses_out_table(sign_slice, data_root, tmp_path):
    """experiment=signs_unseen_arms, tiny: the policy corrects and sees the arms, chest and neck alone;
    `aslexp signing policy=RUN` performs its held-out fold's clips, and the results page's
    leave-glosses-out entry (report: signing_folds) makes its row and figure from that run; a second
    seed's policy on the same fold is a row of its own, each naming its seed."""
    import yaml

    folder = [f"train_motions.folder={sign_slice}", "train_motions.folds=2", "train_motions.seed=2",
              "train_motions.validation_motions=0"]
    clip = sign_slice / "motions" / "upper_body" / "01457.txt"
    metrics = _imitate(tmp_path, data_root, "arms", f"motion.file={clip}", "motion.name=01457", *folder,
                       experiment="signs_unseen_arms")
    assert metrics["train_motions"]["signs"]["held_out_gloss"] == "again"
    performed = _signing(tmp_path / "results", data_root, "folds", f"signing.motions={sign_slice}",
                         f"policy={tmp_path / 'arms'}")
    records = [r for r in performed["records"] if "policy" in r["rewards"]]
    assert records and {r["gloss"] for r in records} <= set(metrics["train_motions"]["signs"]["test_glosses"])
    _imitate(tmp_path, data_root, "arms_seed1", f"motion.file={clip}", "motion.name=01457", *folder, "seed=1",
             experiment="signs_unseen_arms")
    other = _signing(tmp_path / "results", data_root, "folds_seed1", f"signing.motions={sign_slice}",
                     f"policy={tmp_path / 'arms_seed1'}")
    entry = {"id": "folds", "title": "leave glosses out", "beside": "aslexp headline", "thesis": {"source": "none"},
             "overlay": "signs_standing_residual_quiet", "job": "signing", "command": "aslexp signing",
             "engine": "mujoco", "reward": "upper_body_table6_4_run3", "report": "signing_folds",
             "runs": [{"folders": ["results/folds*"], "machine": "a test"}],
             "earlier": {"link": "docs/imitation_upper_body.md#x", "section": "x"},
             "figures": [{"path": "docs/img/folds.png", "caption": "the clips' differences"}]}
    (tmp_path / "catalogue.yaml").write_text(yaml.safe_dump({"entries": [entry]}))
    env = {**os.environ, "ASLEXP_DATA_ROOT": str(data_root), "MPLBACKEND": "Agg"}
    proc = job_process.run([sys.executable, "-m", "aslexp.cli", "report", "--results", "--catalogue", "catalogue.yaml",
                            "--outputs", str(tmp_path), "--snapshots", "snapshots", "--page", "page.md"],
                           cwd=tmp_path, capture_output=True, text=True, timeout=300, env=env)
    assert proc.returncode == 0, proc.stderr[-3000:]
    page = (tmp_path / "page.md").read_text()
    for seed, performed_by in ((0, records), (1, [r for r in other["records"] if "policy" in r["rewards"]])):
        gap = np.mean([r["rewards"]["policy"] - r["rewards"]["controller"] for r in performed_by])
        row = next(line for line in page.splitlines() if line.startswith("| 01457 (again), fold")
                   and line.split("|")[1].strip().endswith(f"seed {seed}"))
        assert f"{gap:+.4f}" in row and f"| {len(performed_by)} (" in row
    snapshot = json.loads((tmp_path / "snapshots" / "folds.json").read_text())
    fold = str(metrics["train_motions"]["signs"]["fold"])
    assert [r["key"] for r in snapshot["rows"]] == [f"{fold}/seed 0", f"{fold}/seed 1"]
    from PIL import Image

    with Image.open(tmp_path / "docs" / "img" / "folds.png") as image:
        assert image.size[0] > image.size[1]


@pytest.fixture(scope="module")
def wrists_slice(data_root, tmp_path_factory) -> Path:
    """The slice extracted as experiment=signs_unseen_wrists's header says: Pose's hand points kept."""
    from aslexp.pose.extract_cli import extract_main

    arrays = data_root / "keypoints" / "wlasl-mediapipe-pose"
    if not arrays.is_dir():
        pytest.skip(f"the shared WLASL pose arrays are not under {data_root}")
    out = tmp_path_factory.mktemp("signs_wrists")
    with contextlib.redirect_stdout(io.StringIO()):
        code = extract_main([*(str(arrays / f"{v}.npy") for v in SLICE), "--motions", "--pose-hand-points",
                             "--out", str(out), "--wlasl", str(data_root / "wlasl" / "WLASL_v0.3.json"), "--quiet"])
    assert code == 0
    return out


def test_the_wrists_policy_corrects_and_sees_the_wrists_its_pool_moves(sign_slice, wrists_slice, data_root):
    """experiment=signs_unseen_wrists: its pool's clips move their wrists (the arms-only pool's stand at
    0), and the policy corrects and sees the wrists beside the arms, chest and neck, the fingers not."""
    from aslexp.envs.imitation import ImitationEnv
    from aslexp.jobs._imitation import training_pool

    def built(experiment: str, folder: Path):
        cfg = compose("imitate", [f"experiment={experiment}", "motion='00433'", f"train_motions.folder={folder}",
                                  "train_motions.folds=2", "train_motions.seed=2", "train_motions.validation_motions=0",
                                  f"data_root={data_root}"])
        setup = ImitationSetup.from_config(cfg, data_root)
        return setup, training_pool(cfg, setup), ImitationEnv.from_setup(setup)

    wrists, wrists_pool, wrists_env = built("signs_unseen_wrists", wrists_slice)
    arms, arms_pool, arms_env = built("signs_unseen_arms", sign_slice)
    joints = wrists_env.layout.joints
    starts = np.cumsum([0] + [j.dof for j in joints])  # each joint's first column of the joint vector
    columns = {g: [c for j, s in zip(joints, starts) if j.group == g for c in range(s, s + j.dof)]
               for g in ("wrist", "fingers")}
    assert len(columns["wrist"]) == 2 and columns["fingers"]

    def wrist_spread(setup, pool, folder: Path) -> float:  # the extracted clips: the thesis' signs move theirs
        clips = [m for m in pool.motions if str(folder) in str(m.source)]
        batch = BatchedImitationEnv.from_setup(1, setup, motions=clips)
        frames = [r.joints_many(np.linspace(0.0, d, 50)) for r, d in zip(batch.pool.references, batch.pool.durations)]
        batch.close()
        assert len(clips) >= 4
        return max(float(np.std(f[:, columns["wrist"]], axis=0).max()) for f in frames)

    assert wrist_spread(arms, arms_pool, sign_slice) == 0.0 and wrist_spread(wrists, wrists_pool, wrists_slice) > 0.05
    seen, _ = wrists_env.policy_seen
    assert set(columns["wrist"]) <= set(seen) and not set(columns["fingers"]) & set(seen)
    assert wrists_env.action_space.shape[0] == arms_env.action_space.shape[0] + 2
    action = np.zeros(wrists_env.action_space.shape, np.float32)
    action[list(seen).index(columns["wrist"][0])] = 1.0
    assert np.flatnonzero(wrists_env.physical_action(action)).tolist() == [columns["wrist"][0]]
    for env in (wrists_env, arms_env):
        env.close()
