"""Trial files, study results and trained policies as Python objects."""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from . import _native


@dataclass
class Trial:
    """One trial file's contents (robofish.io 1.0, or the lab's pre-2020 layout).

    ``poses`` is ``(entities, frames, 3)``: x, y (cm, tank centre 0, y up) and heading (rad),
    NaN where an entity was not tracked. ``fishprobe`` is the ``/fishprobe`` group of files
    fishprobe wrote (kind, policy, fish_model, seed, goal_radius_cm, goal_frames, active_goal,
    command_frames, command_turns, control_start_frame, config, program_version), else None.
    """

    path: str
    frame_rate_hz: float
    world_size_cm: list[float]
    names: list[str]
    categories: list[str]
    poses: np.ndarray
    goals: np.ndarray
    fishprobe: dict[str, Any] | None
    attributes: dict[str, Any] = field(default_factory=dict)
    entities: list[dict[str, Any]] = field(default_factory=list)

    @property
    def robot(self) -> np.ndarray | None:
        """Poses of the first robot entity, ``(frames, 3)``, or None."""
        for i, c in enumerate(self.categories):
            if c.lower() == "robot":
                return self.poses[i]
        return None

    @property
    def fish(self) -> np.ndarray:
        """Poses of the fish, ``(fish, frames, 3)``."""
        idx = [i for i, c in enumerate(self.categories) if c.lower() in ("fish", "organism")]
        return self.poses[idx]

    @property
    def duration_s(self) -> float:
        return self.poses.shape[1] / self.frame_rate_hz if self.frame_rate_hz else 0.0


def read_trial(path: str | os.PathLike) -> Trial:
    """Reads a trial file. Raises ``OSError`` when it cannot be read and ``ValueError`` when it
    is not a trial file (naming what is wrong)."""
    d = _native.read_trial(os.fspath(path))
    return Trial(path=os.fspath(path), **d)


#: Largest ``results.json`` :func:`load_results` reads, as the report (``fishprobe_io``'s
#: ``MAX_TEXT_BYTES``, 16 MiB); a study's results are tens of kilobytes.
MAX_RESULTS_BYTES = 16 << 20


def load_results(study: str | os.PathLike) -> dict[str, Any]:
    """A study's ``analysis/results.json`` (``fishprobe run``/``analyze``'s output) as Python
    objects: ``study`` is the study directory or the file itself. Missing values (no test
    possible) are ``None``. Raises ``FileNotFoundError`` when there are no results and
    ``ValueError`` for a file that is not JSON or larger than :data:`MAX_RESULTS_BYTES`."""
    path = _native.results_path(os.fspath(study))
    try:
        with open(path, "rb") as f:
            # Read no further than the report does (a device or a wrong file would fill
            # memory): a study's results are tens of kilobytes.
            data = f.read(MAX_RESULTS_BYTES + 1)
    except FileNotFoundError:
        raise FileNotFoundError(
            f"{path}: no results (run `fishprobe analyze` or `fishprobe run` on the study first)"
        ) from None
    if len(data) > MAX_RESULTS_BYTES:
        raise ValueError(
            f"{path}: larger than {MAX_RESULTS_BYTES >> 20} MiB, so not a results file "
            "(reading stopped there)"
        )
    try:
        return json.loads(data)
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        raise ValueError(f"{path}: not a results file ({e})") from None


class Policy:
    """A trained robot policy: a policy directory (``fishprobe train`` or
    ``fishprobe.train``'s output) or ``"onnx:PATH"`` (an ONNX file of the policy contract,
    ``docs/onnx-models.md``).

    ``act(obs)`` takes one observation ``(180,)`` or a batch ``(n, 180)`` and returns the
    turns, ``(1,)`` or ``(n, 1)`` float32, as the environment's action space wants them. By
    default the policy's mean action; ``stochastic=True`` samples (directories only).
    """

    def __init__(self, path: str | os.PathLike, stochastic: bool = False, seed: int = 0) -> None:
        p = os.fspath(path)
        file = p[len("onnx:"):] if p.startswith("onnx:") else p
        if not p.startswith("scripted:") and not os.path.exists(file):
            raise FileNotFoundError(f"{file}: no such policy directory or ONNX file")
        self._policy = _native.Policy(p, stochastic=stochastic, seed=seed)
        self.path = p
        self.name: str = self._policy.name
        #: SHA-256 of the weights that decide its actions: what every trial it drives records
        #: as ``trial.fishprobe["config"]["policy_sha256"]``, so that trials of a policy
        #: retrained under the same name are told apart.
        self.sha256: str = self._policy.sha256
        #: The environment settings it was trained with, where it records them (a policy that
        #: ``fishprobe train`` or ``fishprobe.train`` made): ``{"frames_per_action": ...,
        #: "frame_rate_hz": ..., "observation": {...}}``, to merge into an environment's ``settings=`` so that it
        #: acts as often and sees what it was trained to (``None`` for an ONNX file, which
        #: records neither). The CLI refuses other settings by name; an environment cannot
        #: know which policy will act in it, so here the caller merges them.
        t = self._policy.trained_settings
        self.settings: dict | None = json.loads(t) if t is not None else None

    def act(self, obs) -> np.ndarray:
        o = np.asarray(obs, dtype=np.float32)
        if o.ndim == 1:
            return self._policy.act(np.ascontiguousarray(o[None, :])).reshape(1)
        if o.ndim != 2:
            raise ValueError(f"observations of shape {o.shape}: expected (obs_dim,) or (n, obs_dim)")
        return self._policy.act(np.ascontiguousarray(o)).reshape(-1, 1)

    def __repr__(self) -> str:
        return f"Policy({self.path!r}, name={self.name!r}, sha256={self.sha256[:12]!r})"


def support_scores(path: str | os.PathLike, model: Any = None) -> dict[str, np.ndarray]:
    """How far each view of the fish in a trial file lies outside a data-driven model's training
    support (the OOD objective's score, ``docs/guide/ood.md``): 0 at the training views'
    median, 1 at their 95th percentile. The views ``fishprobe ood-report --trials`` scores: one
    per fish and tracked frame, from the start of closed-loop control.

    Args:
        path: a trial file (e.g. a live trial recorded under an OOD policy).
        model: the model whose support to score against (default ``"ConvNet"``, the shipped
            M_ConvNet; ``"convnet:FILE"`` or ``"onnx:FILE"`` with their support file).

    Returns:
        ``{"frame": int64 (n,), "fish": int64 (n,), "score": float32 (n,),
        "position": float32 (n, 2) cm}``.
    """
    return dict(_native.support_scores(os.fspath(path), model))

