"""The OOD task from Python: ``fishprobe/OOD-v0`` and ``task="ood"``."""

from __future__ import annotations

import json

import gymnasium as gym
import numpy as np
import pytest

import fishprobe
from fishprobe.models import Attractor

# With floor 0 and a cap no score reaches, the OOD reward of a step is exactly the mean support
# score of the fish's views in it, less the wall penalty when the robot came near a wall.
PLAIN = {"task": {"ood_score_floor": 0.0, "ood_score_cap": 1000.0, "ood_weight": 1.0}}


def _reward_is_the_score(reward, score, near_wall, penalty):
    return reward == pytest.approx(score - (penalty if near_wall else 0.0), abs=1e-5)


def _scores_are_the_rewards(env):
    """Six steps of `env` (reset with seed 0): each reward is the step's score, less the wall
    penalty when the robot came near a wall. Returns the scores."""
    penalty = env.unwrapped.settings["task"]["wall_penalty"]
    env.reset(seed=0)
    scores = []
    for k in range(6):
        _, reward, _, _, info = env.step(np.array([0.8 * (k % 3 - 1)], np.float32))
        assert _reward_is_the_score(reward, info["support_score"], info["robot_near_wall"], penalty)
        scores.append(info["support_score"])
    assert np.all(np.isfinite(scores)) and min(scores) >= 0.0
    return scores


def test_the_ood_env_rewards_the_support_score():
    env = gym.make("fishprobe/OOD-v0", settings=PLAIN)
    settings = env.unwrapped.settings
    assert settings["task"]["objective"] == "ood"
    assert env.unwrapped.model_name == "ConvNet"
    assert max(_scores_are_the_rewards(env)) > 0.0
    # The default reward pays only the part of a score beyond the support's edge (floor 1).
    default = fishprobe.LeadToGoalEnv(model="ConvNet", task="ood")
    default.reset(seed=0)
    _, reward, _, _, info = default.step(np.zeros(1, np.float32))
    assert reward <= info["support_score"] + 1e-6
    # The lead-to-goal task has no support score.
    goal = fishprobe.LeadToGoalEnv(model="ConvNet")
    goal.reset(seed=0)
    assert "support_score" not in goal.step(np.zeros(1, np.float32))[4]


def test_the_vector_ood_env_reports_each_environments_score():
    envs = gym.make_vec("fishprobe/OOD-v0", num_envs=3, settings=PLAIN)
    envs.reset(seed=1)
    penalty = fishprobe.LeadToGoalEnv(model="ConvNet", settings=PLAIN).settings["task"]["wall_penalty"]
    for _ in range(3):
        _, rewards, _, _, info = envs.step(np.zeros((3, 1), np.float32))
        scores = info["support_score"]
        assert scores.shape == (3,) and np.all(np.isfinite(scores))
        # Each reward is its environment's score, or that less the wall penalty.
        for r, s in zip(rewards, scores):
            assert r == pytest.approx(s, abs=1e-5) or r == pytest.approx(s - penalty, abs=1e-5)
    goal = gym.make_vec("fishprobe/LeadToGoal-v0", num_envs=2, model="Zone")
    goal.reset(seed=0)
    assert "support_score" not in goal.step(np.zeros((2, 1), np.float32))[4]


def test_the_ood_task_needs_a_data_driven_model():
    with pytest.raises(ValueError, match="not data-driven"):
        gym.make("fishprobe/OOD-v0", model="Zone")
    with pytest.raises(ValueError, match="not data-driven"):
        fishprobe.VectorEnv(2, model="Follow", task="ood")
    with pytest.raises(ValueError, match="task 'race'"):
        fishprobe.LeadToGoalEnv(model="ConvNet", task="race")
    with pytest.raises(TypeError, match="settings"):
        fishprobe.LeadToGoalEnv(model="ConvNet", task="ood", settings=[1])


def test_training_on_the_ood_task_needs_a_data_driven_model(tmp_path):
    with pytest.raises(ValueError, match="not data-driven"):
        fishprobe.train("Zone", tmp_path / "run", preset="smoke", settings={"task": {"objective": "ood"}})
    assert not (tmp_path / "run").exists()


def test_support_scores_of_a_trial_are_what_ood_report_scores(tmp_path, cli):
    trial = tmp_path / "t.hdf5"
    cli("simulate", "--model", "ConvNet", "--robot", "goals", "--minutes", "0.5", "--seed", "2",
        "--out", trial)
    s = fishprobe.support_scores(trial)
    n = len(s["score"])
    assert n == 751 and s["position"].shape == (n, 2)  # the start pose, then 750 frames
    assert (s["fish"] == 0).all() and (np.diff(s["frame"]) == 1).all()
    assert s["score"].dtype == np.float32 and (s["score"] >= 0).all()
    r = cli("ood-report", "--trials", trial, "--compare-trials", trial, "--model", "ConvNet",
            "--out", tmp_path / "report", "--json")
    d = [x for x in json.loads(r.stdout)["distributions"] if x["label"] == "OOD policy"][0]
    scores = s["score"].astype(np.float64)
    assert d["views"] == n
    assert d["median"] == pytest.approx(np.quantile(scores, 0.5), abs=1e-9)
    assert d["p95"] == pytest.approx(np.quantile(scores, 0.95), abs=1e-9)
    assert d["beyond_support"] == pytest.approx(np.mean(scores > 1.0), abs=1e-12)
    with pytest.raises(ValueError, match="not data-driven"):
        fishprobe.support_scores(trial, model="Zone")
    with pytest.raises(ValueError, match="not data-driven"):
        fishprobe.support_scores(trial, model=Attractor())


def test_training_with_a_yardstick_measures_what_the_cli_measures(tmp_path, cli):
    yard = {"episodes": 1, "minutes": 0.2, "band": 0.2}
    ood = {"task": {"objective": "ood"}}
    out = tmp_path / "py"
    fishprobe.train("ConvNet", out, preset="smoke", steps=500, settings=ood, callback=None,
                    ood_yardstick="scripted:goal-seeker", yardstick=yard)
    cli("train", "--model", "ConvNet", "--task", "ood", "--preset", "smoke", "--steps", "500",
        "--ood-yardstick", "scripted:goal-seeker", "--ood-yardstick-episodes", "1",
        "--ood-yardstick-minutes", "0.2", "--ood-yardstick-band", "0.2", "--out", tmp_path / "cli")
    measured = json.loads((out / "yardstick.json").read_text())
    assert measured == json.loads((tmp_path / "cli" / "yardstick.json").read_text())
    assert measured["config"]["band"] == pytest.approx(0.2) and measured["views"] > 0
    task = json.loads((out / "params.json").read_text())["env"]["task"]
    assert task["ood_score_floor"] == pytest.approx(max(measured["score"], 0.0), abs=1e-6)
    assert task["ood_score_cap"] == pytest.approx(task["ood_score_floor"] + 0.2, abs=1e-5)
    assert task["ood_weight"] == pytest.approx(5.0, abs=1e-5)
    assert (out / "yardstick" / "yardstick_000.hdf5").is_file()
    assert (out / "policy.safetensors").read_bytes() == (
        tmp_path / "cli" / "policy.safetensors").read_bytes()


def test_bad_yardsticks_are_refused_before_the_run_exists(tmp_path):
    ood = {"task": {"objective": "ood"}}
    cases = [
        (dict(settings=ood, ood_yardstick="scripted:goal-seeker", yardstick={"band": 0}),
         "ood_yardstick.band"),
        (dict(settings=ood, ood_yardstick="scripted:goal-seeker", yardstick={"bnad": 0.1}),
         "bnad"),
        (dict(settings=ood, ood_yardstick="scripted:goal-seeker", yardstick={"band": float("nan")}),
         "numbers must be finite"),
        (dict(settings=ood, ood_yardstick="scripted:goal-seeker", yardstick={"seed": 2**70}),
         r"seed = 1180591620717411303424 is too large for a whole number"),
        (dict(ood_yardstick="scripted:goal-seeker"), "OOD task only"),
        (dict(settings=ood, yardstick={"band": 0.1}), "need ood_yardstick"),
    ]
    for k, (kwargs, why) in enumerate(cases):
        with pytest.raises(ValueError, match=why):
            fishprobe.train("ConvNet", tmp_path / f"run{k}", preset="smoke", callback=None, **kwargs)
        assert not (tmp_path / f"run{k}").exists()
    # A yardstick policy that does not exist: refused naming it, no run written.
    with pytest.raises(RuntimeError, match="no-such-policy"):
        fishprobe.train("ConvNet", tmp_path / "missing", preset="smoke", settings=ood,
                        callback=None, ood_yardstick=str(tmp_path / "no-such-policy"))
    assert not (tmp_path / "missing").exists()


def test_the_ood_env_can_reward_an_ensembles_disagreement(tmp_path, cli, shared_data):
    pairs = shared_data / "guppy-pairs" / "legacy"
    train = sorted((pairs / "train").glob("*.hdf5"))[:2]
    held_out = sorted((pairs / "validation").glob("*.hdf5"))[:1]
    assert train and held_out, f"no guppy pairs under {pairs}"
    weights = tmp_path / "convnet.safetensors"
    cli("fit-convnet", "--data", *train, "--validation", *held_out, "--out", weights,
        "--max-epochs", "1", "--members", "2", "--no-baselines")
    ensemble = json.loads((tmp_path / "convnet.safetensors.disagreement.json").read_text())
    assert len(ensemble["members"]) == 1
    dis = {"task": {**PLAIN["task"], "ood_score": "disagreement"}}
    env = gym.make("fishprobe/OOD-v0", model=f"convnet:{weights}", settings=dis)
    assert env.unwrapped.settings["task"]["ood_score"] == "disagreement"
    # The reward is the disagreement score, as it was the support score above.
    _scores_are_the_rewards(env)
    # The shipped weights come without an ensemble: the error says how to make one.
    with pytest.raises(ValueError, match="--members"):
        gym.make("fishprobe/OOD-v0", settings=dis)
