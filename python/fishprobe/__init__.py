"""fishprobe from Python: the RoboFish simulator as Gymnasium environments, fish models written
in Python, fishprobe's PPO trainer, and trial files and study results as numpy arrays.

>>> import gymnasium as gym, fishprobe
>>> env = gym.make("fishprobe/LeadToGoal-v0", model="Zone")
>>> obs, info = env.reset(seed=0)
>>> obs.shape
(180,)

The simulation runs in Rust (the same code as the ``fishprobe`` command line); this package
moves numbers between it and numpy. See ``python/README.md`` and ``docs/guide/python.md``.
"""

from __future__ import annotations

import gymnasium as _gym

from . import _native
from .env import LeadToGoalEnv
from .files import Policy, load_results, read_trial, support_scores
from .models import FishModel
from .training import evaluate, train
from .vector import VectorEnv

__version__ = _native.__version__

#: The built-in fish models, in the paper's order (also accepted: ``"onnx:PATH"``, a spec dict,
#: or a Python object with ``decide(views)``).
MODELS: tuple[str, ...] = tuple(_native.model_names())

__all__ = [
    "FishModel",
    "LeadToGoalEnv",
    "MODELS",
    "Policy",
    "VectorEnv",
    "evaluate",
    "load_results",
    "read_trial",
    "support_scores",
    "train",
]

if "fishprobe/LeadToGoal-v0" not in _gym.registry:
    _gym.register(
        id="fishprobe/LeadToGoal-v0",
        entry_point="fishprobe.env:LeadToGoalEnv",
        vector_entry_point="fishprobe.vector:VectorEnv",
    )
# The OOD task: the robot is rewarded for driving the fish's views out of its
# model's training support; the shipped M_ConvNet by default.
if "fishprobe/OOD-v0" not in _gym.registry:
    _gym.register(
        id="fishprobe/OOD-v0",
        entry_point="fishprobe.env:LeadToGoalEnv",
        vector_entry_point="fishprobe.vector:VectorEnv",
        kwargs={"task": "ood", "model": "ConvNet"},
    )
