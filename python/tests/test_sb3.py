"""Stable-Baselines3's PPO on fishprobe's vector environment. Opt-in (it installs nothing and
takes about a minute): FISHPROBE_SB3=1 with stable-baselines3 installed, e.g.

    pip install "./python[sb3,test]" && FISHPROBE_SB3=1 pytest python/tests/test_sb3.py
"""

import os

import numpy as np
import pytest

pytestmark = pytest.mark.sb3

if os.environ.get("FISHPROBE_SB3") != "1":
    pytest.skip("opt-in: set FISHPROBE_SB3=1 (needs stable-baselines3)", allow_module_level=True)


def test_sb3_ppo_trains_on_the_vector_env(tmp_path):
    sb3 = pytest.importorskip("stable_baselines3")
    from stable_baselines3.common.env_checker import check_env  # noqa: F401
    from stable_baselines3.common.vec_env import VecMonitor

    from fishprobe.sb3 import VecEnv

    env = VecMonitor(VecEnv(8, model="Zone", seed=0))
    model = sb3.PPO("MlpPolicy", env, n_steps=256, batch_size=256, n_epochs=2, seed=0, verbose=0)
    model.learn(total_timesteps=4096)
    assert model.num_timesteps >= 4096
    obs = env.reset()
    actions, _ = model.predict(obs, deterministic=True)
    assert actions.shape == (8, 1) and np.isfinite(actions).all()
    path = tmp_path / "ppo_zone"
    model.save(path)
    assert path.with_suffix(".zip").exists()
