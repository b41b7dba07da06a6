"""Stable-Baselines3's ``VecEnv`` interface over fishprobe's vector environment.

Importable without Stable-Baselines3: the class then stands alone with the same methods; with
SB3 installed it subclasses ``stable_baselines3.common.vec_env.VecEnv``, so SB3's algorithms
accept it::

    from stable_baselines3 import PPO
    from fishprobe.sb3 import VecEnv
    model = PPO("MlpPolicy", VecEnv(16, model="Zone", seed=0)).learn(100_000)

SB3's conventions: ``reset()`` returns only observations; ``step_wait()`` returns
``(obs, rewards, dones, infos)`` with ``dones = terminated | truncated``, one info dict per
environment, and for an ended episode ``info["terminal_observation"]`` and
``info["TimeLimit.truncated"]`` (the next episode has already begun).
"""

from __future__ import annotations

from typing import Any, Sequence

import numpy as np

from .vector import VectorEnv as _GymVectorEnv

try:  # pragma: no cover - depends on what is installed
    from stable_baselines3.common.vec_env.base_vec_env import VecEnv as _Base

    HAVE_SB3 = True
except ImportError:  # pragma: no cover
    _Base = object
    HAVE_SB3 = False


class VecEnv(_Base):  # type: ignore[misc, valid-type]
    """SB3 ``VecEnv`` of ``num_envs`` fishprobe environments (arguments as
    :class:`fishprobe.VectorEnv`)."""

    def __init__(self, num_envs: int = 16, seed: int | None = 0, **kwargs: Any) -> None:
        self.venv = _GymVectorEnv(num_envs, seed=seed, **kwargs)
        obs_space = self.venv.single_observation_space
        act_space = self.venv.single_action_space
        if HAVE_SB3:
            super().__init__(num_envs, obs_space, act_space)
        else:
            self.num_envs = num_envs
            self.observation_space = obs_space
            self.action_space = act_space
        self._seed = seed
        self._actions: np.ndarray | None = None
        self.render_mode = None

    def reset(self) -> np.ndarray:
        obs, _ = self.venv.reset(seed=self._seed)
        # Later resets continue with fresh episodes, not the same ones again.
        self._seed = None if self._seed is None else self._seed + 1
        return obs

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = np.asarray(actions, dtype=np.float32).reshape(self.num_envs, -1)

    def step_wait(self):
        if self._actions is None:
            raise RuntimeError("step_async() must come before step_wait()")
        obs, rewards, terminated, truncated, info = self.venv.step(self._actions)
        self._actions = None
        dones = terminated | truncated
        infos: list[dict[str, Any]] = [
            {"goals_reached": int(g)} for g in info["goals_reached"]
        ]
        if "final_obs" in info:
            fin = info["final_info"]
            for i in np.flatnonzero(info["_final_obs"]):
                infos[i]["terminal_observation"] = info["final_obs"][i]
                infos[i]["TimeLimit.truncated"] = bool(truncated[i] and not terminated[i])
                infos[i]["episode"] = {
                    "r": float(fin["episode_return"][i]),
                    "l": int(self.venv.max_episode_steps),
                    "goals": int(fin["goals"][i]),
                }
        return obs, rewards.astype(np.float32), dones, infos

    def step(self, actions: np.ndarray):
        self.step_async(actions)
        return self.step_wait()

    def close(self) -> None:
        self.venv.close()

    def seed(self, seed: int | None = None) -> Sequence[None | int]:
        self._seed = seed
        return [seed] * self.num_envs

    def get_images(self) -> Sequence[np.ndarray | None]:
        return [self.venv._venv.render(i, self.venv.render_size) for i in range(self.num_envs)]

    def get_attr(self, attr_name: str, indices=None) -> list[Any]:
        return [getattr(self.venv, attr_name)] * len(self._indices(indices))

    def set_attr(self, attr_name: str, value: Any, indices=None) -> None:
        setattr(self.venv, attr_name, value)

    def env_method(self, method_name: str, *args, indices=None, **kwargs) -> list[Any]:
        raise AttributeError(
            f"fishprobe environments run in Rust; they have no per-environment method {method_name!r}"
        )

    def env_is_wrapped(self, wrapper_class, indices=None) -> list[bool]:
        return [False] * len(self._indices(indices))

    def _indices(self, indices) -> list[int]:
        if indices is None:
            return list(range(self.num_envs))
        if isinstance(indices, int):
            return [indices]
        return list(indices)
