import math

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import fishprobe


@pytest.mark.parametrize("mode", ["training", "evaluation"])
@pytest.mark.parametrize("model", fishprobe.MODELS)
def test_check_env_passes_for_every_builtin_model(model, mode):
    env = gym.make("fishprobe/LeadToGoal-v0", model=model, mode=mode, render_mode="rgb_array")
    check_env(env.unwrapped, skip_render_check=False)


def test_spaces_follow_the_issue():
    env = fishprobe.LeadToGoalEnv(model="Zone")
    assert env.observation_space == gym.spaces.Box(0, 1, (180,), np.float32)
    assert env.action_space == gym.spaces.Box(-math.pi, math.pi, (1,), np.float32)


def test_same_seed_same_episode_and_info_contents():
    def run(seed):
        env = fishprobe.LeadToGoalEnv(model="Force")
        obs, info = env.reset(seed=seed)
        out = [obs]
        rng = np.random.default_rng(0)
        for _ in range(20):
            obs, r, term, trunc, info = env.step(rng.uniform(-1, 1, 1).astype(np.float32))
            out.append(obs)
            assert term is False
        return np.stack(out), info

    a, info = run(3)
    b, _ = run(3)
    c, _ = run(4)
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)
    for key in ("goals_reached", "goals_total", "robot_wall_contacts", "fish_wall_contacts",
                "robot_pose", "fish_poses", "goal", "frame"):
        assert key in info
    assert info["fish_poses"].shape == (1, 3)
    assert info["frame"] == 20 * 25


def test_truncated_at_the_time_limit_and_never_terminated():
    env = fishprobe.LeadToGoalEnv(model="Zone", settings={"task": {"training_episode_actions": 5}})
    env.reset(seed=0)
    flags = [env.step(np.zeros(1, np.float32))[2:4] for _ in range(5)]
    assert flags == [(False, False)] * 4 + [(False, True)]
    assert env.max_episode_steps == 5


def test_evaluation_mode_runs_fifteen_minutes():
    assert fishprobe.LeadToGoalEnv(model="Zone", mode="evaluation").max_episode_steps == 900
    assert fishprobe.LeadToGoalEnv(model="Zone").max_episode_steps == 41


def test_model_as_spec_dict_changes_the_fish():
    def fish_after(model):
        env = fishprobe.LeadToGoalEnv(model=model)
        env.reset(seed=0)
        for _ in range(5):
            *_, info = env.step(np.zeros(1, np.float32))
        return info["fish_poses"]

    default = fish_after("Follow")
    assert np.array_equal(default, fish_after({"model": "Follow"}))
    slow = fish_after({"model": "Follow", "speed_cm_s": 1.0})
    assert not np.array_equal(default, slow)
    assert fishprobe.LeadToGoalEnv(model={"model": "Follow", "speed_cm_s": 1.0}).model_spec[
        "speed_cm_s"] == 1.0


def test_several_fish():
    env = fishprobe.LeadToGoalEnv(model="Zone", fish_count=3)
    _, info = env.reset(seed=0)
    assert info["fish_poses"].shape == (3, 3)
    # A group of 16 with the centroid rule steps; 17 is refused by name.
    env = fishprobe.LeadToGoalEnv(model="Zone", fish_count=16,
                                  settings={"task": {"group_goal": "centroid"}})
    obs, info = env.reset(seed=1)
    for _ in range(5):
        obs, reward, terminated, truncated, info = env.step(np.array([0.2], np.float32))
    assert info["fish_poses"].shape == (16, 3) and np.isfinite(obs).all()
    with pytest.raises(ValueError, match="fish_count"):
        fishprobe.LeadToGoalEnv(model="Zone", fish_count=17)
    with pytest.raises(ValueError, match="group_goal_fraction"):
        fishprobe.LeadToGoalEnv(model="Zone", fish_count=4,
                                settings={"task": {"group_goal_fraction": 0}})


def test_render_is_a_top_down_picture():
    env = fishprobe.LeadToGoalEnv(model="Zone", render_mode="rgb_array", render_size=200)
    env.reset(seed=0)
    img = env.render()
    assert img.shape == (200, 200, 3) and img.dtype == np.uint8
    # The robot is drawn red, the fish blue, the goal green.
    colours = {tuple(c) for c in img.reshape(-1, 3)}
    assert (214, 39, 40) in colours and (31, 119, 180) in colours and (120, 200, 120) in colours
    assert fishprobe.LeadToGoalEnv(model="Zone").render() is None


def test_record_video_wrapper_accepts_the_frames(tmp_path):
    pytest.importorskip("moviepy")
    env = gym.wrappers.RecordVideo(
        gym.make("fishprobe/LeadToGoal-v0", model="Zone", render_mode="rgb_array"),
        str(tmp_path), episode_trigger=lambda e: True,
    )
    env.reset(seed=0)
    for _ in range(3):
        env.step(env.action_space.sample())
    env.close()


# --- bad input: clear Python exceptions, and the environment stays usable --------------------

def test_wrong_action_shapes_and_nan_are_refused_without_harm():
    env = fishprobe.LeadToGoalEnv(model="Zone")
    env.reset(seed=0)
    reference = fishprobe.LeadToGoalEnv(model="Zone")
    reference.reset(seed=0)
    with pytest.raises(ValueError, match="shape"):
        env.step(np.zeros(2, np.float32))
    with pytest.raises(ValueError, match="(?i)finite|nan"):
        env.step(np.array([np.nan], np.float32))
    with pytest.raises(ValueError, match="(?i)finite|inf"):
        env.step(np.array([np.inf], np.float32))
    with pytest.raises((TypeError, ValueError)):
        env.step("left")
    a = env.step(np.array([0.2], np.float32))
    b = reference.step(np.array([0.2], np.float32))
    np.testing.assert_array_equal(a[0], b[0])


def test_step_before_reset_is_an_error():
    with pytest.raises(RuntimeError, match="(?i)reset"):
        fishprobe.LeadToGoalEnv(model="Zone").step(np.zeros(1, np.float32))


def test_unknown_models_and_bad_settings_name_the_problem(tmp_path):
    with pytest.raises(ValueError, match="Zonk.*known models"):
        fishprobe.LeadToGoalEnv(model="Zonk")
    with pytest.raises(ValueError, match="speed_cm_s"):
        fishprobe.LeadToGoalEnv(model={"model": "Follow", "speed_cm_s": -1.0})
    with pytest.raises(ValueError, match="bogus"):
        fishprobe.LeadToGoalEnv(model={"model": "Follow", "bogus": 1})
    with pytest.raises(ValueError, match="frame_rate_hz"):
        fishprobe.LeadToGoalEnv(model="Zone", settings={"frame_rate_hz": -25})
    with pytest.raises(ValueError, match="tank_size|unknown field"):
        fishprobe.LeadToGoalEnv(model="Zone", settings={"tank_size": 3})
    with pytest.raises(ValueError, match="fish_count"):
        fishprobe.LeadToGoalEnv(model="Zone", fish_count=100)
    with pytest.raises(ValueError, match="mode"):
        fishprobe.LeadToGoalEnv(model="Zone", mode="racing")
    with pytest.raises(TypeError, match="decide"):
        fishprobe.LeadToGoalEnv(model=42)
    missing = tmp_path / "nope.onnx"
    with pytest.raises(ValueError, match="nope.onnx"):
        fishprobe.LeadToGoalEnv(model=f"onnx:{missing}")
    garbage = tmp_path / "garbage.onnx"
    garbage.write_bytes(b"not a model at all")
    with pytest.raises(ValueError, match="garbage.onnx"):
        fishprobe.LeadToGoalEnv(model=f"onnx:{garbage}")


def test_reset_options_are_refused():
    with pytest.raises(ValueError, match="options"):
        fishprobe.LeadToGoalEnv(model="Zone").reset(seed=0, options={"x": 1})


def test_render_collection_gathers_one_frame_per_step():
    env = gym.wrappers.RenderCollection(
        fishprobe.LeadToGoalEnv(model="Zone", render_mode="rgb_array", render_size=64))
    env.reset(seed=0)
    for _ in range(3):
        env.step(env.action_space.sample())
    frames = env.render()
    assert len(frames) == 4 and all(f.shape == (64, 64, 3) for f in frames)
    assert not np.array_equal(frames[0], frames[-1])  # the agents moved
