"""fishprobe's own PPO trainer, and the evaluation task, from Python."""

from __future__ import annotations

import os
import sys
from typing import Any, Callable

from . import _native


def _print_progress(stats: dict) -> None:
    print(
        f"iteration {stats['iteration']} steps {stats['timesteps']} "
        f"return {stats['episode_return_mean']:.3f} goals/episode {stats['goals_per_episode']:.3f} "
        f"{stats['steps_per_s']:.0f} steps/s",
        file=sys.stderr,
        flush=True,
    )


def train(
    model: Any,
    out: str | os.PathLike,
    preset: str = "paper",
    seed: int = 0,
    steps: int | None = None,
    settings: dict | None = None,
    ppo: dict | None = None,
    resume: bool = False,
    callback: Callable[[dict], Any] | None = _print_progress,
    ood_yardstick: str | os.PathLike | None = None,
    yardstick: dict | None = None,
) -> str:
    """Trains a robot policy against ``model`` with fishprobe's PPO, exactly as
    ``fishprobe train`` does, and writes the same run directory to ``out`` (``params.json``,
    ``progress.csv``, ``result.json``, ``checkpoints/``, ``policy.safetensors``).

    Args:
        model: as for :class:`fishprobe.LeadToGoalEnv`, including a Python fish model.
        out: the run directory (one writer at a time: a second ``train`` into it is refused).
        preset: ``"paper"``, ``"published"``, ``"quick"`` or ``"smoke"`` (see ``fishprobe train
            --help``).
        seed: master seed; the same seed gives the same policy.
        steps: environment steps (overrides the preset's). With ``resume=True``: raises the
            run's budget to this many, so that a finished run trains on (it ends where a run
            of this many steps from the start ends; a lower budget is refused).
        settings: environment settings dict (``env`` table of a settings file).
        ppo: PPO settings overriding the preset's, by field (``{"num_sgd_iter": 10}``).
        resume: continue the run in ``out`` from its last checkpoint (pass the same model).
        callback: called with each iteration's statistics (a dict, as a line of
            ``result.json``); by default a line on stderr. ``None``: silent.
        ood_yardstick: with the OOD task (``settings={"task": {"objective": "ood"}}``), a
            lead-to-goal policy (a training directory, ``"onnx:FILE"`` or ``"scripted:NAME"``)
            whose percentile of the OOD score (support or disagreement, as the settings'
            ``ood_score``) the reward counts time beyond, measured before
            training, as ``fishprobe train --ood-yardstick`` does (its episodes in
            ``out/yardstick/``, what was measured in ``out/yardstick.json``;
            ``docs/guide/ood.md``).
        yardstick: how the yardstick is measured, overriding its defaults by field
            (``{"quantile": 0.95, "band": 0.15, "episodes": 6, "minutes": 5.0, "seed": 0}``,
            the ``[ood_yardstick]`` section of ``docs/settings.md``).

    Returns:
        The path of the trained policy file. Ctrl+C stops between iterations; ``resume=True``
        continues from the last checkpoint.
    """
    return _native.train(
        model,
        os.fspath(out),
        preset=preset,
        seed=int(seed),
        steps=None if steps is None else int(steps),
        settings=settings,
        ppo=ppo,
        resume=resume,
        callback=callback,
        ood_yardstick=None if ood_yardstick is None else os.fspath(ood_yardstick),
        yardstick=yardstick,
    )


def evaluate(
    policy: str | os.PathLike,
    model: Any,
    out: str | os.PathLike,
    episodes: int = 18,
    minutes: float = 15.0,
    seed: int = 0,
    settings: dict | None = None,
) -> dict:
    """Runs a policy on the paper's evaluation task against ``model``, exactly as
    ``fishprobe evaluate`` does: ``episodes`` episodes of ``minutes`` (the paper: 15), one
    robofish.io trial file per episode (``out/trial_000.hdf5``, ...) and ``out/summary.csv``.

    Args:
        policy: a training directory, ``"onnx:FILE"`` (e.g. a Stable-Baselines3 policy) or
            ``"scripted:goal-seeker"`` / ``"scripted:fetch-and-lead"`` / ``"scripted:random"``;
            its mean action.
        model: as for :func:`train`, including a fish model written in Python (which the
            command line cannot run).
        out: the output directory (one writer at a time; ``FileExistsError`` if it already
            holds an evaluation, whose trials the new one would overwrite in part).
        episodes, minutes, seed: the episodes; the same seed gives the same episodes.
        settings: environment settings dict (``env`` table of a settings file).

    Returns:
        A dict: ``goals``, ``mean_time_to_goal_s`` (NaN for an episode without a goal) and
        ``wall_contacts`` per episode (numpy arrays), ``files`` (the trial files),
        ``goals_mean`` and ``goals_sd`` (sample s.d.), ``policy`` and ``model``.
    """
    return _native.evaluate(
        os.fspath(policy),
        model,
        os.fspath(out),
        episodes=int(episodes),
        minutes=float(minutes),
        seed=int(seed),
        settings=settings,
    )
