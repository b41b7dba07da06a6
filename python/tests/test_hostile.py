"""The Python surfaces under attack: fish classes that misbehave, environments stepped with bad
actions, from several threads or pickled, and damaged trial files. Each gives a clean, named
Python exception or the behaviour docs/guide/python.md documents; none crashes the
interpreter or hangs."""

import pickle
import threading
import time

import numpy as np
import pytest

import fishprobe


class Answers(fishprobe.FishModel):
    """A fish whose answer is computed by ``how(views)``."""

    name = "Answers"

    def __init__(self, how):
        self.how = how

    def decide(self, views):
        return self.how(views)


def n_of(views):
    return len(views.me)


# --- fish classes ------------------------------------------------------------------------


@pytest.mark.parametrize(
    "how,error,match",
    [
        (lambda v: (np.full(n_of(v), np.inf), np.zeros(n_of(v))), ValueError, "finite"),
        (lambda v: (np.zeros(n_of(v)), np.full(n_of(v), -np.inf)), ValueError, "finite"),
        (lambda v: (np.zeros((n_of(v), 2)), np.zeros(n_of(v))), ValueError, "shape"),
        (lambda v: (np.zeros(0), np.zeros(0)), ValueError, "shape"),
        (lambda v: (np.array(["fast"] * n_of(v)), np.zeros(n_of(v))), TypeError, "speed"),
        (lambda v: (np.array([None] * n_of(v)), np.zeros(n_of(v))), ValueError, "finite"),
        (lambda v: None, TypeError, "speed, turn_rate"),
        (lambda v: (np.zeros(n_of(v)),), TypeError, "speed, turn_rate"),
    ],
)
def test_wrong_answers_of_a_fish_class_are_named_and_spoil_only_the_episode(how, error, match):
    fish = Answers(how)
    env = fishprobe.LeadToGoalEnv(model=fish)
    env.reset(seed=0)
    with pytest.raises(error, match=match):
        env.step(np.zeros(1, np.float32))
    # The episode is spoiled, not the environment: a step says reset, and after a reset a
    # fish that answers well runs.
    with pytest.raises(RuntimeError, match="reset"):
        env.step(np.zeros(1, np.float32))
    fish.how = lambda v: (np.zeros(n_of(v)), np.zeros(n_of(v)))
    env.reset(seed=0)
    obs, *_ = env.step(np.zeros(1, np.float32))
    assert np.isfinite(obs).all()


@pytest.mark.parametrize("dtype", [np.int64, np.int8, np.float16, np.float64, bool])
def test_numeric_dtypes_are_taken_as_numbers(dtype):
    # Any real numeric dtype is a number of cm/s and rad/s (converted to float32).
    still = Answers(lambda v: (np.zeros(n_of(v), dtype), np.zeros(n_of(v), dtype)))
    env = fishprobe.LeadToGoalEnv(model=still)
    _, info0 = env.reset(seed=0)
    *_, info = env.step(np.zeros(1, np.float32))
    np.testing.assert_allclose(info["fish_poses"][:, :2], info0["fish_poses"][:, :2], atol=1e-5)


def test_answers_that_are_views_of_the_inputs_are_copied_before_use():
    # Speed and turn rate as views into the arrays fishprobe handed in (the fish's own speed
    # column of `me`, and a slice of `walls`), then the inputs scribbled over: the step uses
    # the values as they were returned, and runs exactly like a fish returning copies.
    def views_of_inputs(v):
        speed, turn = v.me[:, 3], v.walls[:, 0]
        out = (np.clip(speed, 0, 5), np.clip(turn * 0.0, 0, 0))
        return out

    def copies(v):
        return tuple(np.array(a, copy=True) for a in views_of_inputs(v))

    def scribbling(v):
        out = views_of_inputs(v)
        v.me[:] = 1e30
        v.walls[:] = np.nan
        return out

    poses = []
    for how in (views_of_inputs, copies):
        env = fishprobe.LeadToGoalEnv(model=Answers(how))
        env.reset(seed=3)
        for _ in range(3):
            *_, info = env.step(np.full(1, 0.1, np.float32))
        poses.append(info["fish_poses"])
    np.testing.assert_array_equal(poses[0], poses[1])
    env = fishprobe.LeadToGoalEnv(model=Answers(scribbling))
    env.reset(seed=3)
    for _ in range(3):
        obs, *_ = env.step(np.full(1, 0.1, np.float32))
    assert np.isfinite(obs).all()


def test_a_fish_that_blocks_holds_its_step_and_nothing_else():
    # fishprobe does not interrupt a Python fish: a slow `decide` makes the step as slow
    # (docs/guide/python.md), and other Python threads run meanwhile.
    def slow(v):
        time.sleep(0.05)
        return np.zeros(n_of(v)), np.zeros(n_of(v))

    env = fishprobe.LeadToGoalEnv(model=Answers(slow))
    env.reset(seed=0)
    ticks = []
    stop = threading.Event()

    def ticker():
        while not stop.is_set():
            ticks.append(time.monotonic())
            time.sleep(0.01)

    t = threading.Thread(target=ticker)
    t.start()
    start = time.monotonic()
    env.step(np.zeros(1, np.float32))  # 25 frames of 50 ms
    took = time.monotonic() - start
    stop.set()
    t.join()
    assert took >= 25 * 0.05
    assert len(ticks) > 20, "other threads did not run while the fish slept"


# --- environments ----------------------------------------------------------------------


def test_huge_and_odd_dtype_actions():
    env = fishprobe.LeadToGoalEnv(model="Zone")
    env.reset(seed=0)
    # Finite but huge: refused (a turn is an angle in [-pi, pi]) or clipped, never NaN state.
    for a in [np.array([1e30], np.float32), np.array([-1e30]), np.array([3.5e38])]:
        try:
            obs, *_ = env.step(a)
            assert np.isfinite(obs).all()
        except ValueError as e:
            assert "turn" in str(e) or "range" in str(e) or "finite" in str(e)
    # float64 and integer actions are numbers; strings, None and objects are not.
    env.step(np.array([0.1], np.float64))
    env.step(np.array([0], np.int64))
    env.step([0.1])
    for bad in ["left", None, object(), {"turn": 0.1}]:
        with pytest.raises((TypeError, ValueError)):
            env.step(bad)
    # Wrong shapes, with and without a batch.
    for bad in [np.zeros((1, 2), np.float32), np.zeros(0, np.float32), np.zeros((2, 1))]:
        with pytest.raises(ValueError, match="shape"):
            env.step(bad)


def test_stepping_after_the_episode_ended_without_reset_is_an_error():
    env = fishprobe.LeadToGoalEnv(model="Zone", mode="training")  # 41-s episodes
    env.reset(seed=0)
    truncated = False
    for _ in range(60):
        *_, terminated, truncated, _ = env.step(np.zeros(1, np.float32))
        if terminated or truncated:
            break
    assert truncated
    with pytest.raises(RuntimeError, match="(?i)reset"):
        env.step(np.zeros(1, np.float32))
    env.reset()
    env.step(np.zeros(1, np.float32))


def test_vector_env_bad_actions_are_refused_without_harm():
    v = fishprobe.VectorEnv(3, model="Zone", seed=0)
    v.reset()
    for bad in [
        np.full((3, 1), np.nan, np.float32),
        np.full((3, 1), np.inf, np.float32),
        np.zeros((2, 1), np.float32),
        np.zeros((3, 2), np.float32),
        "left",
    ]:
        with pytest.raises((TypeError, ValueError)):
            v.step(bad)
    obs, *_ = v.step(np.zeros((3, 1), np.float64))
    assert np.isfinite(obs).all()


def test_one_environment_stepped_from_several_threads_stays_consistent():
    # Steps from several threads are serialised (or refused with a RuntimeError); the
    # environment ends in a state some sequence of those steps explains: the number of
    # frames it advanced is the number of steps that succeeded.
    env = fishprobe.LeadToGoalEnv(model="Zone", mode="evaluation")  # 900-s episodes
    env.reset(seed=0)
    done, refused = [], []

    def worker():
        for _ in range(20):
            try:
                env.step(np.zeros(1, np.float32))
                done.append(1)
            except RuntimeError as e:
                refused.append(str(e))

    threads = [threading.Thread(target=worker) for _ in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(timeout=120)
        assert not t.is_alive(), "a step from a thread hung"
    assert len(done) + len(refused) == 80
    _, _, _, _, info = env.step(np.zeros(1, np.float32))
    assert info["frame"] == 25 * (len(done) + 1)
    for r in refused:
        assert "borrow" in r.lower() or "thread" in r.lower(), r


def test_pickling_an_environment_is_refused_by_name():
    env = fishprobe.LeadToGoalEnv(model="Zone")
    env.reset(seed=0)
    with pytest.raises((TypeError, pickle.PicklingError), match="(?i)pickle"):
        pickle.dumps(env)
    v = fishprobe.VectorEnv(2, model="Zone", seed=0)
    with pytest.raises((TypeError, pickle.PicklingError), match="(?i)pickle"):
        pickle.dumps(v)


# --- trial files -----------------------------------------------------------------------


def test_damaged_trial_files_raise_clean_errors(tmp_path, fishprobe_bin):
    import subprocess

    good = tmp_path / "good.hdf5"
    subprocess.run(
        [str(fishprobe_bin), "simulate", "--model", "Zone", "--minutes", "0.5", "--out", str(good)],
        check=True,
        capture_output=True,
    )
    data = good.read_bytes()
    rng = np.random.default_rng(0)
    damaged = []
    for cut in [0, 7, 8, 100, len(data) // 3, len(data) // 2, len(data) - 1]:
        damaged.append(data[:cut])
    for _ in range(60):
        b = bytearray(data)
        for at in rng.integers(0, len(b), size=int(rng.integers(1, 20))):
            b[at] = int(rng.integers(0, 256))
        damaged.append(bytes(b))
    for _ in range(10):
        b = bytearray(data)
        at = int(rng.integers(0, len(b) - 512))
        b[at : at + 512] = b"\0" * 512
        damaged.append(bytes(b))
    outcomes = {"read": 0, "refused": 0}
    for i, d in enumerate(damaged):
        p = tmp_path / f"d{i:03}.hdf5"
        p.write_bytes(d)
        try:
            t = fishprobe.read_trial(p)
            assert t.poses.ndim == 3
            outcomes["read"] += 1
        except (OSError, ValueError) as e:
            assert p.name in str(e), str(e)
            outcomes["refused"] += 1
    assert outcomes["refused"] >= 7, outcomes  # every cut file at least
