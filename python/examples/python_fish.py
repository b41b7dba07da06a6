"""A fish model written in Python, tested the fishprobe way: train a robot policy against it
with fishprobe's own PPO, then see how well that policy leads it, and how well it leads the
built-in models.

    python python/examples/python_fish.py --out runs/Shy
"""

from __future__ import annotations

import argparse

import numpy as np

import fishprobe


class Shy(fishprobe.FishModel):
    """Follows the robot from a distance: swims towards it when farther than ``keep_cm``, away
    when closer, and turns away from walls it is about to hit."""

    name = "Shy"

    def __init__(self, speed: float = 6.3, keep_cm: float = 12.0, max_turn: float = 6.0):
        self.speed, self.keep_cm, self.max_turn = speed, keep_cm, max_turn

    def decide(self, views):
        me, robot = views.me, views.others[:, 0]
        dx, dy = robot[:, 0] - me[:, 0], robot[:, 1] - me[:, 1]
        towards = np.arctan2(dy, dx)
        far = np.hypot(dx, dy) > self.keep_cm
        target = np.where(far, towards, towards + np.pi)
        # Walls closer than 5 cm push the target heading towards the tank's centre.
        near_wall = views.walls.min(axis=1) < 5.0
        target = np.where(near_wall, np.arctan2(-me[:, 1], -me[:, 0]), target)
        error = (target - me[:, 2] + np.pi) % (2 * np.pi) - np.pi
        turn = np.clip(error / views.dt, -self.max_turn, self.max_turn)
        return np.full(len(me), self.speed), turn


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("--out", default="runs/Shy")
    p.add_argument("--preset", default="quick")
    p.add_argument("--steps", type=int, default=None)
    a = p.parse_args()
    fishprobe.train(Shy(), a.out, preset=a.preset, steps=a.steps, seed=0)
    for model in (Shy(), "Follow", "Zone", "Force"):
        name = getattr(model, "name", model)
        # fishprobe evaluate's episodes (6 of 15 minutes), trial files in OUT/eval-NAME/.
        r = fishprobe.evaluate(a.out, model, f"{a.out}/eval-{name}", episodes=6)
        print(f"pi_Shy leading {name}: {r['goals_mean']:.1f} ± {r['goals_sd']:.1f} "
              "goals per 15-minute episode")


if __name__ == "__main__":
    main()
