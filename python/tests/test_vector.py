import numpy as np
import pytest
from gymnasium.vector import AutoresetMode

import fishprobe
from fishprobe.sb3 import VecEnv as SB3VecEnv

SHORT = {"task": {"training_episode_actions": 4}}


def test_spaces_metadata_and_shapes():
    v = fishprobe.VectorEnv(8, model="Zone", seed=0)
    assert v.metadata["autoreset_mode"] == AutoresetMode.SAME_STEP
    assert v.single_observation_space.shape == (180,)
    assert v.observation_space.shape == (8, 180)
    assert v.action_space.shape == (8, 1)
    obs, info = v.reset()
    assert obs.shape == (8, 180) and obs.dtype == np.float32
    obs, rew, term, trunc, info = v.step(v.action_space.sample())
    assert rew.shape == (8,) and term.dtype == bool and trunc.shape == (8,)
    assert info["goals_reached"].shape == (8,)


def test_matches_single_environments_seeded_alike():
    """Environment i of a vector environment is the single environment with its derived
    seed: the same steps give the same observations."""
    v = fishprobe.VectorEnv(3, model="Force")
    obs_v, _ = v.reset(seed=11)
    rng = np.random.default_rng(1)
    acts = rng.uniform(-3, 3, (10, 3, 1)).astype(np.float32)
    rows = [obs_v]
    for a in acts:
        rows.append(v.step(a)[0])
    v2 = fishprobe.VectorEnv(3, model="Force")
    rows2 = [v2.reset(seed=11)[0]] + [v2.step(a)[0] for a in acts]
    np.testing.assert_array_equal(np.stack(rows), np.stack(rows2))


def test_same_step_autoreset_reports_the_final_observation():
    v = fishprobe.VectorEnv(4, model="Zone", settings=SHORT, seed=0)
    v.reset()
    a = np.zeros((4, 1), np.float32)
    for _ in range(3):
        obs, _, _, trunc, info = v.step(a)
        assert not trunc.any() and "final_obs" not in info
    obs, _, term, trunc, info = v.step(a)
    assert trunc.all() and not term.any()
    assert info["_final_obs"].all()
    final = np.stack(info["final_obs"])
    assert final.shape == (4, 180)
    assert not np.array_equal(final, obs)  # obs already begins the next episode
    assert info["final_info"]["goals"].shape == (4,)
    # The next episode goes on normally.
    obs, _, _, trunc, _ = v.step(a)
    assert not trunc.any()


def test_bad_actions_leave_every_environment_untouched():
    v = fishprobe.VectorEnv(4, model="Zone", seed=5)
    w = fishprobe.VectorEnv(4, model="Zone", seed=5)
    v.reset(), w.reset()
    with pytest.raises(ValueError, match="shape"):
        v.step(np.zeros((3, 1), np.float32))
    bad = np.zeros((4, 1), np.float32)
    bad[2] = np.nan
    with pytest.raises(ValueError, match="(?i)finite|nan"):
        v.step(bad)
    a = np.full((4, 1), 0.5, np.float32)
    np.testing.assert_array_equal(v.step(a)[0], w.step(a)[0])


def test_absurd_sizes_are_refused():
    for n in (0, 10**9):
        with pytest.raises(ValueError, match="num_envs"):
            fishprobe.VectorEnv(n, model="Zone")
    with pytest.raises(TypeError):
        fishprobe.VectorEnv(2.5, model="Zone")
    with pytest.raises(RuntimeError, match="reset"):
        fishprobe.VectorEnv(2, model="Zone").step(np.zeros((2, 1), np.float32))


def _reinforce(step_fn, obs, n, iters=6, horizon=8, seed=0):
    """A numpy REINFORCE loop on a linear Gaussian policy: it must run through the interface
    and change the weights; it is not expected to learn in so few steps."""
    rng = np.random.default_rng(seed)
    w = np.zeros(obs.shape[1], np.float32)
    for _ in range(iters):
        grads, rewards = [], []
        for _ in range(horizon):
            mean = obs @ w
            a = (mean + rng.normal(0, 0.5, n)).astype(np.float32)
            grads.append(((a - mean) / 0.25)[:, None] * obs)
            obs, r = step_fn(a[:, None])
            rewards.append(r)
        ret = np.cumsum(np.array(rewards)[::-1], axis=0)[::-1]
        adv = ret - ret.mean()
        w += 1e-3 * np.mean([g * adv[t][:, None] for t, g in enumerate(grads)], axis=(0, 1))
    return w


def test_numpy_reinforce_through_the_gymnasium_vector_env():
    v = fishprobe.VectorEnv(8, model="Zone", settings=SHORT, seed=0)
    obs, _ = v.reset()

    def step(a):
        o, r, *_ = v.step(a)
        return o, r

    w = _reinforce(step, obs, 8)
    assert np.isfinite(w).all() and np.abs(w).sum() > 0


def test_numpy_reinforce_through_the_sb3_adapter():
    v = SB3VecEnv(8, model="Zone", settings=SHORT, seed=0)
    obs = v.reset()
    assert obs.shape == (8, 180)
    dones_seen = []

    def step(a):
        o, r, d, infos = v.step(a)
        assert len(infos) == 8
        for i in np.flatnonzero(d):
            assert infos[i]["terminal_observation"].shape == (180,)
            assert infos[i]["TimeLimit.truncated"] is True
            dones_seen.append(i)
        return o, r

    w = _reinforce(step, obs, 8)
    assert np.isfinite(w).all() and dones_seen
    assert v.env_is_wrapped(object) == [False] * 8
    assert v.get_attr("model_name") == ["Zone"] * 8


def test_gymnasium_make_vec_uses_the_rust_vector_env():
    import gymnasium as gym

    v = gym.make_vec("fishprobe/LeadToGoal-v0", num_envs=4,
                     vectorization_mode="vector_entry_point", model="Force")
    assert isinstance(v, fishprobe.VectorEnv) and v.model_name == "Force"
    obs, _ = v.reset(seed=0)
    assert obs.shape == (4, 180)
