"""Trial files, study results and policies as Python objects."""

import json
import math
import os

import numpy as np
import pytest

import fishprobe


def test_reads_a_live_robofish_trial(shared_data):
    path = shared_data / "robot-fish" / "Q12I_Fri_Dec__6_11_59_34_2019_Robotracker.hdf5"
    t = fishprobe.read_trial(path)
    assert t.frame_rate_hz == pytest.approx(20.0)  # this live recording's sampling
    assert t.world_size_cm == [100.0, 100.0]
    h5py = pytest.importorskip("h5py")
    with h5py.File(path, "r") as f:
        for i, name in enumerate(t.names):
            np.testing.assert_array_equal(t.poses[i, :, :2], f["entities"][name]["positions"][:])
            assert t.categories[i] == f["entities"][name].attrs["category"]
    n, frames, three = t.poses.shape
    assert three == 3 and n == len(t.names) == len(t.categories) and frames > 1000
    assert t.robot is not None and t.robot.shape == (frames, 3)
    assert t.fish.shape[0] >= 1
    tracked = t.fish[0][~np.isnan(t.fish[0][:, 0])]
    assert (np.abs(tracked[:, :2]) <= 50.0 + 1e-3).all()
    assert t.fishprobe is None and t.goals.shape == (0, 2)


def test_reads_the_legacy_layout(shared_data):
    legacy = sorted((shared_data / "guppy-pairs" / "legacy" / "validation").glob("*.hdf5"))
    assert legacy, "no legacy files in the shared data"
    t = fishprobe.read_trial(legacy[0])
    assert t.poses.shape[0] == 2 and t.poses.shape[1] > 100 and t.frame_rate_hz > 0


def test_reads_fishprobes_own_trial_with_its_task(tmp_path, cli):
    out = tmp_path / "trial.hdf5"
    cli("simulate", "--model", "Zone", "--robot", "goals", "--minutes", "1", "--seed", "3",
        "--out", out)
    t = fishprobe.read_trial(out)
    assert t.poses.shape[:2] == (2, 25 * 60 + 1)  # the start pose, then 1500 frames
    m = t.fishprobe
    assert m["kind"] == "sim" and m["fish_model"] == "Zone" and m["seed"] == 3
    assert m["goal_radius_cm"] == pytest.approx(5.0)
    assert len(m["active_goal"]) == t.poses.shape[1]
    assert t.goals.shape[1] == 2 and len(t.goals) >= 1
    assert isinstance(m["config"], dict)
    headings = t.robot[:, 2]
    assert np.isfinite(headings).all() and (np.abs(headings) <= math.pi + 1e-6).all()


def test_bad_files_raise_clear_errors(tmp_path):
    with pytest.raises(OSError, match="missing.hdf5"):
        fishprobe.read_trial(tmp_path / "missing.hdf5")
    junk = tmp_path / "junk.hdf5"
    junk.write_bytes(b"\x89HDF\r\n\x1a\n" + b"\0" * 100)
    with pytest.raises(ValueError, match="junk.hdf5"):
        fishprobe.read_trial(junk)
    with pytest.raises(OSError):
        fishprobe.read_trial(tmp_path)


def test_load_results_reads_a_study_or_its_file(tmp_path):
    study = tmp_path / "study"
    (study / "analysis").mkdir(parents=True)
    doc = {"policies": ["Zone"], "wilcoxon": [{"p": None, "w": 3.0}]}
    (study / "analysis" / "results.json").write_text(json.dumps(doc))
    assert fishprobe.load_results(study) == doc
    assert fishprobe.load_results(study / "analysis" / "results.json") == doc
    with pytest.raises(FileNotFoundError, match="fishprobe analyze"):
        fishprobe.load_results(tmp_path / "elsewhere")
    (study / "analysis" / "results.json").write_text("{not json")
    with pytest.raises(ValueError, match="not a results file"):
        fishprobe.load_results(study)
    (study / "analysis" / "results.json").write_bytes(b"\xff\xfe{}")
    with pytest.raises(ValueError, match="not a results file"):
        fishprobe.load_results(study)
    # A file that never ends is read no further than the limit.
    if os.path.exists("/dev/zero"):
        with pytest.raises(ValueError, match="larger than 16 MiB"):
            fishprobe.load_results("/dev/zero")


def test_policy_acts_on_batches_like_the_cli_policy(smoke_policy, tmp_path, cli):
    p = fishprobe.Policy(smoke_policy)
    assert p.name == "Zone"
    env = fishprobe.VectorEnv(5, model="Zone", seed=0)
    obs, _ = env.reset()
    a = p.act(obs)
    assert a.shape == (5, 1) and a.dtype == np.float32
    assert (np.abs(a) <= math.pi).all()
    np.testing.assert_array_equal(p.act(obs[2]), a[2])
    # The same policy exported to ONNX acts the same.
    onnx = tmp_path / "zone.onnx"
    cli("export", "--policy", smoke_policy, "--onnx", onnx)
    q = fishprobe.Policy(f"onnx:{onnx}")
    np.testing.assert_allclose(q.act(obs), a, atol=1e-5)
    # An ONNX file exports the mean: there is no Gaussian to sample, and asking is an error,
    # not a silent mean.
    with pytest.raises(ValueError, match="Gaussian"):
        fishprobe.Policy(f"onnx:{onnx}", stochastic=True)
    # A directory samples: same seed, same actions; another seed, others.
    s0, s0b, s1 = (fishprobe.Policy(smoke_policy, stochastic=True, seed=k) for k in (0, 0, 1))
    np.testing.assert_array_equal(s0.act(obs), s0b.act(obs))
    assert not np.array_equal(s0.act(obs), s1.act(obs))


def test_a_policy_says_what_it_was_trained_with(smoke_policy, tmp_path, cli):
    p = fishprobe.Policy(smoke_policy)
    assert p.settings["frames_per_action"] == 25
    assert p.settings["frame_rate_hz"] == 25.0
    assert p.settings["observation"]["heading_bins"] is False
    assert p.settings["observation"]["previous_block_actions"] == 1
    # Merged into an environment's settings, the environment shows it what it was trained on.
    env = fishprobe.LeadToGoalEnv(model="Zone", settings={"task": {"objective": "goal"}, **p.settings})
    assert env.settings["frames_per_action"] == 25
    assert env.settings["frame_rate_hz"] == 25.0
    assert env.settings["observation"] == pytest.approx(p.settings["observation"])
    obs, _ = env.reset(seed=0)
    assert p.act(obs).shape == (1,)
    # An ONNX file records neither.
    onnx = tmp_path / "zone.onnx"
    cli("export", "--policy", smoke_policy, "--onnx", onnx)
    assert fishprobe.Policy(f"onnx:{onnx}").settings is None


def test_policy_errors(tmp_path, smoke_policy):
    with pytest.raises(OSError):
        fishprobe.Policy(tmp_path / "no-such-policy")
    with pytest.raises(ValueError, match="scripted"):
        fishprobe.Policy("scripted:goal-seeker")
    p = fishprobe.Policy(smoke_policy)
    with pytest.raises(ValueError, match="180|observation"):
        p.act(np.zeros((2, 7), np.float32))
    bad = np.zeros((2, 180), np.float32)
    bad[1, 4] = np.nan
    with pytest.raises(ValueError, match="non-finite"):
        p.act(bad)
