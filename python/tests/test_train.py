"""fishprobe.train: the CLI's trainer from Python, with built-in or Python fish models."""

import json

import numpy as np
import pytest

import fishprobe
from fishprobe.models import Attractor


def test_train_writes_the_same_run_as_the_cli(tmp_path, smoke_policy):
    out = tmp_path / "zone"
    seen = []
    path = fishprobe.train("Zone", out, preset="smoke", seed=0, callback=seen.append)
    assert path.endswith("policy.safetensors")
    assert seen and seen[-1]["timesteps"] >= 4096
    for name in ("params.json", "progress.csv", "result.json", "policy.safetensors"):
        assert (out / name).exists(), name
    # Same seed, same settings: the same policy, byte for byte, as `fishprobe train`.
    assert (out / "policy.safetensors").read_bytes() == (
        smoke_policy / "policy.safetensors"
    ).read_bytes()


def test_train_against_a_python_model_and_resume(tmp_path):
    out = tmp_path / "attractor"
    fishprobe.train(Attractor(), out, preset="smoke", seed=1, steps=2048, callback=None)
    params = json.loads((out / "params.json").read_text())
    assert params["model"] == {
        "model": "Python", "class": "fishprobe.models.Attractor", "name": "Attractor"}
    p = fishprobe.Policy(out)
    assert p.name == "Attractor"
    assert p.act(np.zeros(180, np.float32)).shape == (1,)
    # A finished run resumes to the same end; with another model it is refused.
    fishprobe.train(Attractor(), out, resume=True, callback=None)
    with pytest.raises(ValueError, match="Attractor"):
        fishprobe.train("Zone", out, resume=True, callback=None)
    # The run records the trainer's revision; one that another revision started is refused.
    assert params["trainer_revision"] >= 2
    assert params["program_build"].endswith("Python package")
    params["trainer_revision"] = 1
    (out / "params.json").write_text(json.dumps(params))
    with pytest.raises(RuntimeError, match="started by trainer revision 1"):
        fishprobe.train(Attractor(), out, resume=True, callback=None)


def test_a_finished_run_given_more_steps_ends_as_the_longer_run(tmp_path):
    """resume=True with steps raises a run's budget: it trains on, to the policy of a run of
    that many steps from the start, byte for byte; a lower budget is refused."""
    whole, short = tmp_path / "whole", tmp_path / "short"
    fishprobe.train("Zone", whole, preset="smoke", seed=3, steps=2048, callback=None)
    fishprobe.train("Zone", short, preset="smoke", seed=3, steps=1024, callback=None)
    seen = []
    fishprobe.train("Zone", short, resume=True, steps=2048, callback=seen.append)
    assert seen and seen[0]["timesteps"] > 1024 and seen[-1]["timesteps"] >= 2048
    assert json.loads((short / "params.json").read_text())["ppo"]["total_timesteps"] == 2048
    assert (short / "policy.safetensors").read_bytes() == (
        whole / "policy.safetensors").read_bytes()
    with pytest.raises(RuntimeError, match="can only raise it"):
        fishprobe.train("Zone", short, resume=True, steps=1024, callback=None)


def test_interrupted_training_resumes_where_it_stopped(tmp_path):
    class Stop(Exception):
        pass

    def stop_after_two(stats):
        if stats["iteration"] == 2:
            raise Stop

    out = tmp_path / "run"
    with pytest.raises(Stop):
        fishprobe.train("Follow", out, preset="smoke", seed=2, callback=stop_after_two)
    # Continued as if by another build than the one that started it: each line of
    # result.json names the build that made it.
    params = json.loads((out / "params.json").read_text())
    params["program_build"] = "0.1.0 (commit 0123456789ab)"
    (out / "params.json").write_text(json.dumps(params))
    fishprobe.train("Follow", out, preset="smoke", resume=True, callback=None)
    lines = [json.loads(l) for l in (out / "result.json").read_text().splitlines()]
    assert len(lines) > 2
    assert all(l["build"].endswith("Python package") for l in lines)
    whole = tmp_path / "whole"
    fishprobe.train("Follow", whole, preset="smoke", seed=2, callback=None)
    assert (out / "policy.safetensors").read_bytes() == (whole / "policy.safetensors").read_bytes()


def test_bad_training_arguments(tmp_path):
    with pytest.raises(ValueError, match="preset"):
        fishprobe.train("Zone", tmp_path / "a", preset="turbo")
    with pytest.raises(ValueError, match="num_sgd_iter|ppo"):
        fishprobe.train("Zone", tmp_path / "b", preset="smoke", ppo={"num_sgd_iter": -1})
    with pytest.raises(ValueError, match="bogus"):
        fishprobe.train("Zone", tmp_path / "c", preset="smoke", ppo={"bogus": 1})
    with pytest.raises(ValueError, match="Zonk"):
        fishprobe.train("Zonk", tmp_path / "d")
    with pytest.raises(ValueError, match="ppo: numbers must be finite"):
        fishprobe.train("Zone", tmp_path / "e", preset="smoke", ppo={"lr": float("nan")})
    with pytest.raises(ValueError, match="num_sgd_iter"):
        fishprobe.train("Zone", tmp_path / "f", preset="smoke", ppo={"num_sgd_iter": 10**12})
    with pytest.raises(ValueError, match="settings: numbers must be finite"):
        fishprobe.train("Zone", tmp_path / "g", settings={"task": {"goal_radius_cm": float("inf")}})
    # Refused before the run directory is made: nothing is left behind.
    assert list(tmp_path.iterdir()) == []


def test_a_python_model_that_fails_during_training(tmp_path):
    class Bad(fishprobe.FishModel):
        def decide(self, views):
            raise ZeroDivisionError("oops")

    with pytest.raises(RuntimeError, match="oops"):
        fishprobe.train(Bad(), tmp_path / "bad", preset="smoke", callback=None)


def test_a_second_writer_is_refused(tmp_path):
    """One writer per run directory: while another process (here: this test, through the same
    OS lock fishprobe takes) holds the directory, train refuses at once and writes nothing."""
    fcntl = pytest.importorskip("fcntl")
    out = tmp_path / "busy"
    out.mkdir()
    with open(out / ".fishprobe.lock", "w") as held:
        fcntl.flock(held, fcntl.LOCK_EX | fcntl.LOCK_NB)
        with pytest.raises(RuntimeError, match="busy"):
            fishprobe.train("Zone", out, preset="smoke", callback=None)
    assert not (out / "params.json").exists()
    fishprobe.train("Zone", out, preset="smoke", steps=1024, callback=None)
    assert (out / "policy.safetensors").exists()


def test_the_paper_preset_trains_a_python_fish_at_the_published_budget(tmp_path):
    """A Python fish costs a call every frame: the `paper` preset gives its policy the
    published 832,300 steps at 10 epochs, a rule-based fish's sixteen times the steps at 2;
    both at the preset's discount of 0.99."""
    tiny = {"train_batch_size": 64, "num_envs": 16, "sgd_minibatch_size": 32, "hidden": [8]}
    for model, epochs in ((Attractor(), 10), ("Zone", 2)):
        out = tmp_path / str(epochs)
        fishprobe.train(model, out, preset="paper", steps=64, ppo=tiny, callback=None)
        ppo = json.loads((out / "params.json").read_text())["ppo"]
        assert ppo["num_sgd_iter"] == epochs, model
        assert ppo["gamma"] == pytest.approx(0.99), model


def test_evaluate_runs_the_clis_episodes(tmp_path, cli, smoke_policy):
    r = fishprobe.evaluate(smoke_policy, "Zone", tmp_path / "py", episodes=3, minutes=0.5, seed=4)
    cli("evaluate", "--policy", smoke_policy, "--model", "Zone", "--episodes", "3",
        "--minutes", "0.5", "--seed", "4", "--out", tmp_path / "cli")
    # The same episodes as `fishprobe evaluate`: the same summary, goal for goal.
    assert (tmp_path / "py" / "summary.csv").read_text() == (
        tmp_path / "cli" / "summary.csv").read_text()
    assert r["goals"].dtype == np.int64 and len(r["goals"]) == 3
    assert r["goals_mean"] == pytest.approx(r["goals"].mean())
    assert r["goals_sd"] == pytest.approx(r["goals"].std(ddof=1))
    assert [p.rsplit("/", 1)[-1] for p in r["files"]] == [f"trial_{k:03}.hdf5" for k in range(3)]
    trial = fishprobe.read_trial(r["files"][0])
    assert len(trial.fishprobe["goal_frames"]) == r["goals"][0]
    # The trial records which weights drove it.
    sha = fishprobe.Policy(smoke_policy).sha256
    assert len(sha) == 64 and trial.fishprobe["config"]["policy_sha256"] == sha


def test_evaluate_against_a_python_fish(tmp_path):
    r = fishprobe.evaluate("scripted:fetch-and-lead", Attractor(), tmp_path / "ev", episodes=2,
                           minutes=0.3, seed=1)
    assert r["model"] == "Attractor" and len(r["files"]) == 2
    again = fishprobe.evaluate("scripted:fetch-and-lead", Attractor(), tmp_path / "ev2",
                               episodes=2, minutes=0.3, seed=1)
    assert (again["goals"] == r["goals"]).all()  # same seed, same episodes
    assert np.isnan(r["mean_time_to_goal_s"][r["goals"] == 0]).all()


def test_the_random_robot_runs_from_python_and_is_reproducible(tmp_path):
    kw = dict(model="Zone", episodes=2, minutes=0.5, seed=3)
    r = fishprobe.evaluate("scripted:random", out=tmp_path / "a", **kw)
    again = fishprobe.evaluate("scripted:random", out=tmp_path / "b", **kw)
    seeker = fishprobe.evaluate("scripted:goal-seeker", out=tmp_path / "c", **kw)
    def robot(res):
        return fishprobe.read_trial(res["files"][0]).robot

    np.testing.assert_array_equal(robot(r), robot(again))  # same seed, same turns
    assert not np.allclose(robot(r), robot(seeker))
    assert "scripted:random" in str(fishprobe.read_trial(r["files"][0]).fishprobe["policy"])
    # A directory that holds an evaluation is not written into again (it would mix the two).
    before = sorted(p.name for p in (tmp_path / "a").iterdir())
    with pytest.raises(FileExistsError, match="already holds an evaluation"):
        fishprobe.evaluate("scripted:goal-seeker", out=tmp_path / "a", **kw)
    assert sorted(p.name for p in (tmp_path / "a").iterdir()) == before


def test_bad_evaluations_are_refused_before_the_directory_exists(tmp_path):
    cases = [
        (dict(policy="scripted:goal-seeker", model="Zone", episodes=0), ValueError, "episodes"),
        (dict(policy="scripted:goal-seeker", model="Zone", minutes=float("nan")), ValueError,
         "minutes"),
        (dict(policy="scripted:goal-seeker", model="Zone", minutes=1e9), ValueError, "minutes"),
        (dict(policy=tmp_path / "nothing", model="Zone"), RuntimeError, "nothing"),
        (dict(policy="scripted:goal-seeker", model="Nope"), ValueError, "Nope"),
    ]
    for k, (kwargs, kind, why) in enumerate(cases):
        with pytest.raises(kind, match=why):
            fishprobe.evaluate(out=tmp_path / f"ev{k}", **kwargs)
        assert not (tmp_path / f"ev{k}").exists()


def test_a_python_model_that_fails_during_evaluation(tmp_path):
    class Broken(fishprobe.FishModel):
        name = "Broken"

        def decide(self, views):
            raise KeyError("evaluation bug")

    with pytest.raises(RuntimeError, match="evaluation bug") as e:
        fishprobe.evaluate("scripted:goal-seeker", Broken(), tmp_path / "ev", episodes=3, minutes=0.2)
    assert isinstance(e.value.__cause__, KeyError)
