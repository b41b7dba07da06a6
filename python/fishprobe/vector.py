"""Many environments in one: a Gymnasium ``VectorEnv`` over the Rust vector environment."""

from __future__ import annotations

import math
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium.vector import AutoresetMode
from gymnasium.vector.utils import batch_space

from . import _native
from .env import MODES, with_task


class VectorEnv(gym.vector.VectorEnv):
    """``num_envs`` copies of :class:`fishprobe.LeadToGoalEnv`, stepped together in Rust on all
    cores (the GIL is released while they step). Results do not depend on the number of cores.

    Autoreset: ``SAME_STEP`` (declared in ``metadata["autoreset_mode"]``): when an episode ends,
    the environment starts the next at once; the returned observation is the new episode's
    first, the last one is in ``info["final_obs"]`` (masked by ``info["_final_obs"]``) and the
    ended episode's totals in ``info["final_info"]`` (``episode_return``, ``goals``).

    Args:
        num_envs: number of environments (at most 65,536).
        model, mode, fish_count, settings, task: as for :class:`fishprobe.LeadToGoalEnv`
            (with the OOD task, ``info["support_score"]`` holds each environment's mean
            support score of the fish's views in the step).
        seed: seed of the first ``reset()`` when it is called without one.
    """

    metadata = {"autoreset_mode": AutoresetMode.SAME_STEP, "render_modes": ["rgb_array"]}

    def __init__(
        self,
        num_envs: int = 16,
        model: Any = "Zone",
        mode: str = "training",
        fish_count: int | None = None,
        settings: dict | None = None,
        seed: int | None = None,
        render_mode: str | None = None,
        render_size: int = 400,
        task: str | None = None,
    ) -> None:
        if mode not in MODES:
            raise ValueError(f"mode {mode!r}: use 'training' or 'evaluation'")
        if isinstance(num_envs, bool) or not isinstance(num_envs, (int, np.integer)):
            raise TypeError(f"num_envs must be an integer, not {type(num_envs).__name__}")
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"render_mode {render_mode!r}: use None or 'rgb_array'")
        settings = with_task(settings, task)
        self._venv = _native.VecEnv(
            int(num_envs), model, mode=mode, fish_count=fish_count, settings=settings
        )
        self._ood = (settings or {}).get("task", {}).get("objective") == "ood"
        self.num_envs = int(num_envs)
        self.mode = mode
        self.model_name: str = self._venv.model_name
        self.render_mode = render_mode
        self.render_size = int(render_size)
        self.max_episode_steps: int = self._venv.max_episode_steps
        self.single_observation_space = gym.spaces.Box(
            0.0, 1.0, (self._venv.obs_dim,), np.float32
        )
        self.single_action_space = gym.spaces.Box(-math.pi, math.pi, (1,), np.float32)
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self._seed = seed
        self._started = False

    def reset(self, *, seed: int | list[int] | None = None, options: dict | None = None):
        if options:
            raise ValueError(f"reset options {sorted(options)}: this environment takes none")
        if isinstance(seed, (list, tuple)):
            raise ValueError(
                "one seed for all environments: environment i is seeded from it and i"
            )
        if seed is None:
            seed = self._seed
        if seed is None:
            seed = int(np.random.default_rng().integers(0, 2**63 - 1))
        self._np_random, _ = gym.utils.seeding.np_random(int(seed) % 2**32)
        obs = self._venv.reset(int(seed))
        self._started = True
        return obs, {}

    def step(self, actions):
        if not self._started:
            raise RuntimeError("call reset() before step()")
        a = np.asarray(actions, dtype=np.float32)
        if a.shape not in ((self.num_envs,), (self.num_envs, 1)):
            raise ValueError(
                f"actions of shape {a.shape}: expected ({self.num_envs}, 1), one turn per environment"
            )
        obs, rewards, terminated, truncated, final_obs, ended, goals = self._venv.step(
            np.ascontiguousarray(a.reshape(-1))
        )
        info: dict[str, Any] = {"goals_reached": goals, "_goals_reached": np.ones(self.num_envs, bool)}
        if self._ood:
            info["support_score"] = self._venv.support_scores()
            info["_support_score"] = np.ones(self.num_envs, bool)
        if ended.any():
            fo = np.full(self.num_envs, None, dtype=object)
            returns = np.zeros(self.num_envs, np.float32)
            total = np.zeros(self.num_envs, np.int64)
            for i, f in enumerate(self._venv.finished()):
                if f is not None:
                    fo[i] = final_obs[i]
                    returns[i], total[i] = f[0], f[1]
            info["final_obs"] = fo
            info["_final_obs"] = ended
            info["final_info"] = {
                "episode_return": returns,
                "_episode_return": ended,
                "goals": total,
                "_goals": ended,
            }
            info["_final_info"] = ended
        return obs, rewards, terminated, truncated, info

    def render(self):
        if self.render_mode != "rgb_array":
            return None
        return self._venv.render(0, self.render_size)

    def close_extras(self, **kwargs) -> None:
        pass
