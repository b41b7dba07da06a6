"""Fish models written in Python."""

import numpy as np
import pytest

import fishprobe
from fishprobe.models import Attractor


class Still(fishprobe.FishModel):
    def decide(self, views):
        n = len(views.me)
        return np.zeros(n), np.zeros(n)


class Recorder(fishprobe.FishModel):
    name = "Recorder"

    def __init__(self):
        self.seen = []

    def decide(self, views):
        self.seen.append(views)
        n = len(views.me)
        return np.full(n, 5.0), np.full(n, 0.5)


def test_a_python_model_moves_the_fish_as_it_says():
    rec = Recorder()
    env = fishprobe.LeadToGoalEnv(model=rec, fish_count=2)
    _, info0 = env.reset(seed=0)
    *_, info = env.step(np.zeros(1, np.float32))
    assert env.model_name == "Recorder"
    assert len(rec.seen) == 25  # one call per frame, both fish at once
    v = rec.seen[0]
    assert v.me.shape == (2, 5) and v.others.shape == (2, 16, 5)
    assert list(v.n_others) == [2, 2]  # the robot and the other fish
    assert np.isnan(v.others[:, 2:]).all()
    assert v.walls.shape == (2, 4) and (v.walls >= 0).all()
    assert v.dt == pytest.approx(0.04)
    # The robot is seen first.
    np.testing.assert_allclose(v.others[0, 0, :2], info0["robot_pose"][:2], atol=1e-4)
    # 5 cm/s for 1 s, turning 0.5 rad/s: heading +0.5, displacement <= 5 cm (walls may stop it).
    moved = np.linalg.norm(info["fish_poses"][:, :2] - info0["fish_poses"][:, :2], axis=1)
    assert (moved <= 5.0 + 1e-3).all() and (moved > 0).any()
    dh = (info["fish_poses"][:, 2] - info0["fish_poses"][:, 2] + np.pi) % (2 * np.pi) - np.pi
    np.testing.assert_allclose(dh, 0.5, atol=1e-4)


def test_a_still_fish_stays_still_in_the_vector_env():
    v = fishprobe.VectorEnv(4, model=Still(), seed=0)
    v.reset()
    v.step(np.zeros((4, 1), np.float32))
    assert v.model_name == "Still"


def test_the_example_model_follows_the_robot():
    env = fishprobe.LeadToGoalEnv(model=Attractor(speed=10.0))
    _, info = env.reset(seed=2)
    d0 = np.linalg.norm(info["fish_poses"][0, :2] - info["robot_pose"][:2])
    for _ in range(5):
        *_, info = env.step(np.zeros(1, np.float32))
    d1 = np.linalg.norm(info["fish_poses"][0, :2] - info["robot_pose"][:2])
    assert d1 < d0


class Raises(fishprobe.FishModel):
    def __init__(self, after=0):
        self.calls = 0
        self.after = after

    def decide(self, views):
        self.calls += 1
        if self.calls > self.after:
            raise KeyError("my bug")
        n = len(views.me)
        return np.zeros(n), np.zeros(n)


class WrongShape(fishprobe.FishModel):
    def decide(self, views):
        return np.zeros(len(views.me) + 1), np.zeros(len(views.me))


class WrongType(fishprobe.FishModel):
    def decide(self, views):
        return 3


class NaNs(fishprobe.FishModel):
    def decide(self, views):
        n = len(views.me)
        return np.full(n, np.nan), np.zeros(n)


class Text(fishprobe.FishModel):
    def decide(self, views):
        return ["fast"] * len(views.me), np.zeros(len(views.me))


def test_a_model_that_raises_gives_a_runtime_error_with_its_cause_then_reset_works():
    model = Raises(after=30)
    env = fishprobe.LeadToGoalEnv(model=model)
    env.reset(seed=0)
    env.step(np.zeros(1, np.float32))
    with pytest.raises(RuntimeError, match="Raises failed") as e:
        env.step(np.zeros(1, np.float32))
    assert isinstance(e.value.__cause__, KeyError)
    with pytest.raises(RuntimeError, match="reset"):
        env.step(np.zeros(1, np.float32))
    model.after = 10**9
    env.reset(seed=0)
    env.step(np.zeros(1, np.float32))


def test_a_model_that_raises_in_the_vector_env():
    v = fishprobe.VectorEnv(4, model=Raises())
    v.reset(seed=0)
    with pytest.raises(RuntimeError, match="my bug"):
        v.step(np.zeros((4, 1), np.float32))


@pytest.mark.parametrize(
    "model,error,match",
    [
        (WrongShape(), ValueError, "shape"),
        (WrongType(), TypeError, "speed, turn_rate"),
        (NaNs(), ValueError, "finite"),
        (Text(), TypeError, "speed"),
    ],
)
def test_wrong_answers_are_named(model, error, match):
    env = fishprobe.LeadToGoalEnv(model=model)
    env.reset(seed=0)
    with pytest.raises(error, match=match):
        env.step(np.zeros(1, np.float32))


def test_objects_without_decide_are_refused():
    class NoDecide:
        pass

    with pytest.raises(TypeError, match="decide"):
        fishprobe.LeadToGoalEnv(model=NoDecide())

    class BadName(fishprobe.FishModel):
        name = 3

        def decide(self, views):
            return np.zeros(1), np.zeros(1)

    with pytest.raises(TypeError, match="name"):
        fishprobe.LeadToGoalEnv(model=BadName())
