"""The lead-to-goal task (and the OOD task) as a Gymnasium environment."""

from __future__ import annotations

import json
import math
from typing import Any

import gymnasium as gym
import numpy as np

from . import _native

MODES = ("training", "evaluation")
TASKS = ("goal", "ood")


def with_task(settings: dict | None, task: str | None) -> dict | None:
    """``settings`` with ``task.objective`` set to ``task`` (``None``: unchanged)."""
    if task is None:
        return settings
    if task not in TASKS:
        raise ValueError(f"task {task!r}: use 'goal' (lead to goals) or 'ood' (out of the support)")
    if settings is not None and not isinstance(settings, dict):
        raise TypeError(f"settings must be a dict, not {type(settings).__name__}")
    settings = dict(settings or {})
    table = settings.get("task", {})
    if not isinstance(table, dict):
        raise TypeError(f"settings['task'] must be a dict, not {type(table).__name__}")
    settings["task"] = {**table, "objective": task}
    return settings


class LeadToGoalEnv(gym.Env):
    """A robot fish in the 1 x 1 m tank leads ``fish_count`` fish to goals (SPEC §4-§6).

    Observation: ``Box(0, 1, (180,), float32)``, the robot's view (wall rays, the fish and the
    goal in sectors, relative to the robot). Action: ``Box(-pi, pi, (1,), float32)``, the turn
    relative to the robot's heading, held for one second (25 frames). The reward is the task's
    (goal reached, distance shaping, wall penalty). ``terminated`` is never set: the task runs
    until the time limit, where ``truncated`` is set (training: 41 s, evaluation: 900 s, the
    paper's settings).

    Args:
        model: the fish model: a built-in name (``"Zone"``, ``"Follow"``, ``"Force"``,
            ``"ConvNet"``, ``"Guppy"``, ``"Stationary"``), a spec dict with parameters
            (``{"model": "Zone", "speed_cm_s": 5.0}``), ``"onnx:PATH"`` (an ONNX fish model),
            or a Python object with ``decide(views)`` (see :class:`fishprobe.FishModel`).
        mode: ``"training"`` (random goals, 41 s episodes) or ``"evaluation"`` (the fixed goal
            sequence, 900 s).
        fish_count: number of fish, 1 to 16 (default: the settings', 1); with a group,
            ``settings={"task": {"group_goal": "centroid"}}`` says when a goal is reached.
        settings: environment settings as a dict, as the ``env`` table of a settings file
            (``fishprobe config show``); missing fields keep the paper's values.
        task: ``"goal"`` (lead the fish to goals, the paper's task) or ``"ood"`` (drive the
            fish's views out of its model's training support, as ``fishprobe train --task
            ood``; a data-driven model with its support file, e.g. ``"ConvNet"``); sets
            ``settings["task"]["objective"]``. Default: the settings' (``"goal"``).
            ``gym.make("fishprobe/OOD-v0")`` is this environment with ``task="ood"`` and
            ``model="ConvNet"``.
        render_mode: ``None`` or ``"rgb_array"`` (a top-down picture, uint8 H x W x 3).
        render_size: side of the rendered picture in pixels.

    With the OOD task the reward is the OOD reward (``docs/guide/ood.md``) and ``info`` also
    holds ``support_score``, the mean support score of the fish's views in this step.

    ``info`` holds ``goals_reached`` (in this step), ``goals_total`` (this episode),
    ``robot_wall_contacts`` and ``fish_wall_contacts`` (frames clipped at a wall in this
    step), ``robot_pose`` (x, y cm; heading rad), ``fish_poses`` (n x 3), ``goal`` (the active
    goal, cm) and ``frame``.
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 1}

    def __init__(
        self,
        model: Any = "Zone",
        mode: str = "training",
        fish_count: int | None = None,
        settings: dict | None = None,
        render_mode: str | None = None,
        render_size: int = 400,
        task: str | None = None,
    ) -> None:
        if mode not in MODES:
            raise ValueError(f"mode {mode!r}: use 'training' or 'evaluation'")
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"render_mode {render_mode!r}: use None or 'rgb_array'")
        settings = with_task(settings, task)
        self._env = _native.Env(model, mode=mode, fish_count=fish_count, settings=settings)
        self.mode = mode
        self.model_name: str = self._env.model_name
        self.render_mode = render_mode
        self.render_size = int(render_size)
        self.observation_space = gym.spaces.Box(0.0, 1.0, (self._env.obs_dim,), np.float32)
        self.action_space = gym.spaces.Box(-math.pi, math.pi, (1,), np.float32)
        self.max_episode_steps: int = self._env.max_episode_steps
        self.metadata = {**self.metadata, "render_fps": 1}
        self._seeded = False

    @property
    def settings(self) -> dict:
        """The resolved environment settings."""
        return json.loads(self._env.settings)

    @property
    def model_spec(self) -> dict:
        """The fish model and its parameters, as a spec dict."""
        return json.loads(self._env.model_spec)

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        if options:
            raise ValueError(f"reset options {sorted(options)}: this environment takes none")
        if seed is not None:
            native_seed = int(seed)
        elif not self._seeded:
            native_seed = int(self.np_random.integers(0, 2**63 - 1))
        else:
            native_seed = None  # continue the environment's own random streams
        self._seeded = True
        obs, info = self._env.reset(native_seed)
        return obs, info

    def step(self, action):
        a = np.asarray(action, dtype=np.float32)
        if a.size != 1:
            raise ValueError(f"action of shape {a.shape}: expected one turn angle, shape (1,)")
        return self._env.step(float(a.reshape(-1)[0]))

    def render(self):
        if self.render_mode != "rgb_array":
            return None
        return self._env.render(self.render_size)

    def close(self) -> None:
        pass
