"""Fish models written in Python."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np


class FishModel:
    """Base class (optional: any object with ``decide`` works) for a fish model in Python.

    fishprobe calls ``decide(views)`` once per simulation frame (25 per second of simulated
    time) for a batch of fish, and moves each fish by the answer: it turns by
    ``turn_rate * views.dt``, then swims ``speed * views.dt`` along its new heading (and stops
    at the walls).

    ``views`` has, for ``n`` fish (all arrays float32 unless said):

    - ``me``: ``(n, 5)``, the fish's own x, y (cm, tank centre is 0, y up), heading (rad,
      counter-clockwise from +x), vx, vy (cm/s, over the last frame);
    - ``others``: ``(n, 16, 5)``, the other agents the fish sees, the robot first, then the other
      fish (a tank holds up to 16 fish), as ``me``; rows past ``n_others`` are NaN;
    - ``n_others``: ``(n,)`` int64, how many rows of ``others`` are valid;
    - ``walls``: ``(n, 4)``, distances (cm) to the left, right, bottom and top walls;
    - ``time_s``: ``(n,)``, time since the episode began; ``dt``: the frame duration (s);
      ``tank_half_size_cm``: half the tank's side.

    ``decide`` returns ``(speed, turn_rate)``: two arrays of ``n`` finite numbers, cm/s (>= 0;
    negative values are taken as 0) and rad/s. The answer for one fish should depend only on
    that fish's views (how fish are batched is not promised: today the vector environment asks
    for all its fish at once, and ``fishprobe.evaluate`` runs its episodes one after another
    with one model object).

    Calling Python every frame costs time: measured figures are in ``python/README.md``.
    """

    #: The name reports and policy files use (default: the class name).
    name: str

    def decide(self, views: SimpleNamespace) -> tuple[np.ndarray, np.ndarray]:
        raise NotImplementedError


class Attractor(FishModel):
    """An example: swim at ``speed`` towards the robot, turning at most ``max_turn`` rad/s."""

    name = "Attractor"

    def __init__(self, speed: float = 8.0, max_turn: float = 4.0) -> None:
        self.speed = float(speed)
        self.max_turn = float(max_turn)

    def decide(self, views):
        me, robot = views.me, views.others[:, 0]
        bearing = np.arctan2(robot[:, 1] - me[:, 1], robot[:, 0] - me[:, 0])
        error = (bearing - me[:, 2] + np.pi) % (2 * np.pi) - np.pi
        turn = np.clip(error / views.dt, -self.max_turn, self.max_turn)
        return np.full(len(me), self.speed, np.float32), turn.astype(np.float32)
