"""The RoboTracker behaviour (lab/robotracker/fishprobe_robotracker.py) against a stub
`robotracker` module with RoboTracker's names, driving a real `fishprobe live serve`: ticks at
the tracking rate in real time, the way RoboTracker calls a behaviour."""

from __future__ import annotations

import importlib.util
import json
import math
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
SHIM = REPO / "lab" / "robotracker" / "fishprobe_robotracker.py"

# RoboTracker's module as a behaviour sees it: the base class and the action constructors.
STUB = '''
class PythonBehavior:
    def __init__(self):
        pass

class _Action:
    def __init__(self, *args):
        self.args = args
    def __eq__(self, other):
        return type(self) is type(other) and self.args == other.args
    def __repr__(self):
        return type(self).__name__ + repr(self.args)

class RobotActionFlush(_Action): pass
class RobotActionHalt(_Action): pass
class RobotActionToTarget(_Action): pass
class RobotActionDirect(_Action): pass
'''

HZ = 25.0
# The rig's frame in these tests: origin at the tank's top-left corner, y pointing down.
RIG = {"origin_cm": [50.0, 50.0], "flip_y": True}


class Agent:
    """What RoboTracker hands a behaviour for a robot or a fish."""

    def __init__(self, uid, position, orientation):
        self.uid = uid
        self.position = position
        self.orientation = orientation


@pytest.fixture()
def rt(tmp_path, monkeypatch):
    stub = tmp_path / "stub"
    stub.mkdir()
    (stub / "robotracker.py").write_text(STUB)
    monkeypatch.syspath_prepend(str(stub))
    monkeypatch.delitem(sys.modules, "robotracker", raising=False)
    spec = importlib.util.spec_from_file_location("fishprobe_robotracker", SHIM)
    shim = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(shim)
    import robotracker

    return shim, robotracker


class Bridge:
    """`fishprobe live serve` with a short protocol, on a free loopback port."""

    def __init__(self, fishprobe_bin, out: Path, control_s: float = 3.0):
        settings = out.parent / "live.toml"
        settings.write_text(f"habituation_s = 1.0\nrelease_s = 0.5\ncontrol_s = {control_s}\n")
        self.out = out
        self.proc = subprocess.Popen(
            [str(fishprobe_bin), "live", "serve", "--policy", "scripted:goal-seeker",
             "--listen", "127.0.0.1:0", "--out", str(out), "--trials", "1",
             "--config", str(settings)],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        )
        line = self.proc.stderr.readline()
        m = re.search(r"listening on 127\.0\.0\.1:(\d+)", line)
        assert m, f"no address in the bridge's first line: {line!r}"
        self.port = int(m.group(1))

    def finish(self, timeout=20.0):
        out, err = self.proc.communicate(timeout=timeout)
        return self.proc.returncode, out, err

    def kill(self):
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.communicate()


@pytest.fixture()
def bridge(fishprobe_bin, tmp_path):
    made = []

    def start(**kw):
        b = Bridge(fishprobe_bin, tmp_path / "trials", **kw)
        made.append(b)
        return b

    yield start
    for b in made:
        b.kill()


def behaviour(shim, port, **settings):
    s = dict(shim.DEFAULTS, port=port, **RIG)
    s.update(settings)
    return shim.Behavior(layout=None, settings=s)


def ticks(b, seconds, robot, fish, each=None):
    """Calls next_speeds at the tracking rate for `seconds` of wall time (and `each(k)` after
    tick k); returns every tick's actions and the longest call."""
    out, longest = [], 0.0
    start = time.monotonic()
    k = 0
    while time.monotonic() - start < seconds:
        t = time.monotonic()
        out.append(b.next_speeds([robot], fish, 1000.0 / HZ))
        longest = max(longest, time.monotonic() - t)
        if each is not None:
            each(k)
        k += 1
        time.sleep(max(0.0, start + k / HZ - time.monotonic()))
    return out, longest


def kinds(actions):
    return [type(a).__name__ for a in actions]


def test_a_trial_turns_commands_into_target_points_in_the_rigs_frame(rt, bridge):
    shim, robotracker = rt
    br = bridge()
    b = behaviour(shim, br.port)
    # The robot at fishprobe's (10, 10) facing +x: the rig's (60, 40), orientation (1, 0).
    robot = Agent(7, (60.0, 40.0), (1.0, 0.0))
    fish = [Agent(1, (30.0, 70.0), (0.0, -1.0))]  # fishprobe's (-20, -20), heading +y
    b.activate(robot, None)
    seen = []

    def remember(k):
        seen.append(b.last_command)

    log, longest = ticks(b, 6.0, robot, fish, remember)
    code, _, err = br.finish()
    assert code == 0, err

    targets = [a for actions in log for a in actions
               if isinstance(a, robotracker.RobotActionToTarget)]
    assert targets, f"no target in {len(log)} ticks: {log[:5]}"
    # Every target lies step_cm from the robot in the direction heading + turn (fishprobe's
    # frame), mapped into the rig's frame: x + L cos(turn), y - L sin(turn).
    turns = {round(c["turn"], 9) for c in seen if c and not c.get("stop")
             and c.get("type") == "command"}
    L = shim.SIMULATED_STEP_CM
    for a in targets:
        uid, zero, (tx, ty) = a.args
        assert (uid, zero) == (7, 0)
        assert math.hypot(tx - 60.0, ty - 40.0) == pytest.approx(L, abs=1e-9)
        turn = math.atan2(-(ty - 40.0), tx - 60.0)
        assert any(abs(math.remainder(turn - t, math.tau)) < 1e-6 for t in turns)
    # Each target comes after a flush, and nothing but halts in between.
    for actions in log:
        if any(isinstance(a, robotracker.RobotActionToTarget) for a in actions):
            assert kinds(actions) == ["RobotActionFlush", "RobotActionToTarget"]
    # The trial ran to its end: the last words were flush + halt, then quiet.
    assert b.state == "halted" and b.reason == "the trial is done"
    assert kinds(log[-1]) == [], log[-3:]
    last_target = max(k for k, x in enumerate(log) if "RobotActionToTarget" in kinds(x))
    assert any(kinds(x) == ["RobotActionFlush", "RobotActionHalt"] for x in log[last_target:])
    # Never blocked the tracker (the first tick connects and waits for the welcome).
    assert longest < 2.0
    assert max(_durations(b, robot, fish)) < 0.05

    # The bridge recorded the poses in fishprobe's frame.
    h5py = pytest.importorskip("h5py")
    files = list((br.out).glob("*__Real/*.hdf5"))
    assert len(files) == 1, files
    with h5py.File(files[0], "r") as f:
        def category(e):
            c = e.attrs["category"]
            return c.decode() if isinstance(c, bytes) else str(c)

        robots = [e for e in f["entities"].values() if category(e) == "robot"]
        fishes = [e for e in f["entities"].values() if category(e) in ("fish", "organism")]
        assert len(robots) == 1 and len(fishes) == 1
        r = robots[0]["positions"][0]
        assert (float(r[0]), float(r[1])) == pytest.approx((10.0, 10.0), abs=1e-4)
        p = fishes[0]["positions"][-1]
        assert (float(p[0]), float(p[1])) == pytest.approx((-20.0, -20.0), abs=1e-4)


def _durations(b, robot, fish, n=25):
    """How long next_speeds takes once the trial is over (it must stay quick)."""
    out = []
    for _ in range(n):
        t = time.monotonic()
        b.next_speeds([robot], fish, 40.0)
        out.append(time.monotonic() - t)
    return out


def test_a_tracking_gap_halts_the_robot(rt, bridge):
    shim, _ = rt
    br = bridge(control_s=30.0)
    b = behaviour(shim, br.port)
    robot = Agent(3, (50.0, 50.0), (0.0, 1.0))
    fish = [Agent(1, (40.0, 40.0), (1.0, 0.0))]
    b.activate(robot, None)
    ticks(b, 2.5, robot, fish)  # habituation, release, control begins
    assert b.state == "running"
    lost = [Agent(1, (float("nan"), 40.0), (1.0, 0.0))]
    log, longest = ticks(b, 1.5, robot, lost)
    halts = [k for k, x in enumerate(log) if kinds(x) == ["RobotActionFlush", "RobotActionHalt"]]
    assert halts, "no halt within 1.5 s of a lost fish"
    # stale_s is 0.5 s: the halt comes after about 12 frames, well before 25.
    assert halts[0] <= 25, halts
    assert b.last_command["stop"] is True
    assert b.state == "running"  # a stop is not the end: commands resume with tracking
    b.deactivate()
    code, _, err = br.finish()
    assert code == 0, err


def test_a_bridge_that_dies_or_stalls_halts_the_robot_and_never_blocks_a_tick(rt, bridge):
    shim, _ = rt
    br = bridge(control_s=60.0)
    b = behaviour(shim, br.port)
    robot = Agent(5, (50.0, 50.0), (1.0, 0.0))
    fish = [Agent(1, (40.0, 40.0), (1.0, 0.0))]
    b.activate(robot, None)
    ticks(b, 1.0, robot, fish)
    assert b.state == "running"
    # A stalled bridge: ticks stay quick while it reads nothing.
    os.kill(br.proc.pid, signal.SIGSTOP)
    try:
        _, longest = ticks(b, 1.0, robot, fish)
        assert longest < 0.05, f"a tick took {longest:.3f} s while the bridge stalled"
    finally:
        os.kill(br.proc.pid, signal.SIGCONT)
    ticks(b, 0.5, robot, fish)
    assert b.state == "running"
    # A bridge that dies: flush + halt on the next ticks, no exception, then quiet.
    br.kill()
    log, longest = ticks(b, 0.5, robot, fish)
    assert any(kinds(x) == ["RobotActionFlush", "RobotActionHalt"] for x in log), log
    assert b.state == "halted" and "lost" in b.reason
    assert kinds(log[-1]) == []
    assert longest < 0.05


def test_deactivate_ends_the_trial_and_halts(rt, bridge):
    shim, _ = rt
    br = bridge(control_s=60.0)
    b = behaviour(shim, br.port)
    robot = Agent(5, (50.0, 50.0), (1.0, 0.0))
    fish = [Agent(1, (40.0, 40.0), (1.0, 0.0))]
    b.activate(robot, None)
    ticks(b, 2.0, robot, fish)
    assert kinds(b.deactivate()) == ["RobotActionFlush", "RobotActionHalt"]
    assert b.state in ("halting", "halted")
    code, _, err = br.finish()  # the bridge ends the trial at `end` and, with --trials 1, exits
    assert code == 0, err
    files = list(br.out.glob("*__Real/*.hdf5"))
    assert len(files) == 1, files


def test_without_a_bridge_the_robot_is_halted_and_the_connection_retried(rt, tmp_path):
    shim, _ = rt
    import socket

    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()  # nobody listens there now
    b = behaviour(shim, port, retry_s=0.2)
    robot = Agent(9, (50.0, 50.0), (1.0, 0.0))
    b.activate(robot, None)
    log, longest = ticks(b, 0.6, robot, [])
    assert all(kinds(x) == ["RobotActionFlush", "RobotActionHalt"] for x in log)
    assert b.state == "connecting"
    assert longest < 0.5


def test_settings_are_checked_and_a_wrong_file_keeps_the_robot_halted(rt, tmp_path, monkeypatch):
    shim, _ = rt
    bad = tmp_path / "settings.json"
    bad.write_text(json.dumps({"port": 4500, "stepcm": 12}))
    monkeypatch.setenv("FISHPROBE_ROBOTRACKER_SETTINGS", str(bad))
    b = shim.Behavior(layout=None)
    assert "stepcm" in b.problem
    robot = Agent(9, (50.0, 50.0), (1.0, 0.0))
    b.activate(robot, None)
    assert kinds(b.next_speeds([robot], [], 40.0)) == ["RobotActionFlush", "RobotActionHalt"]
    assert b.state == "halted"
    for wrong in ({"step_cm": 0}, {"step_cm": "13"}, {"port": 70000}, {"flip_y": "yes"},
                  {"origin_cm": [0, float("nan")]}, {"tracking_hz": True}):
        bad.write_text(json.dumps(wrong))
        with pytest.raises(shim.SettingsError):
            shim.load_settings(str(bad))
    good = tmp_path / "good.json"
    good.write_text(json.dumps({"port": 4600, "flip_y": True, "origin_cm": [50, 50]}))
    s = shim.load_settings(str(good))
    assert s["port"] == 4600 and s["step_cm"] == shim.SIMULATED_STEP_CM


class FakeBridge:
    """A bridge that misbehaves: it welcomes with `welcome` (a dict, or raw bytes), then sends
    `then` (bytes), or, with `stream`, the same bytes without end while the behaviour reads."""

    def __init__(self, welcome, then=b"", stream=False):
        import socket
        import threading

        self.srv = socket.socket()
        self.srv.bind(("127.0.0.1", 0))
        self.srv.listen(1)
        self.port = self.srv.getsockname()[1]
        self.sent = 0
        self.stop = False

        def serve():
            try:
                conn, _ = self.srv.accept()
            except OSError:
                return
            with conn:
                f = conn.makefile("rb")
                f.readline()  # the hello
                w = welcome if isinstance(welcome, bytes) else (json.dumps(welcome) + "\n").encode()
                conn.sendall(w)
                try:
                    if stream:
                        while not self.stop:
                            conn.sendall(then)
                            self.sent += len(then)
                    elif then:
                        conn.sendall(then)
                        self.sent += len(then)
                    while not self.stop:
                        time.sleep(0.02)
                except OSError:
                    pass

        self.thread = threading.Thread(target=serve, daemon=True)
        self.thread.start()

    def close(self):
        self.stop = True
        self.srv.close()


WELCOME = {"type": "welcome", "protocol": 1, "policy": "P", "habituation_s": 1, "release_s": 1,
           "control_s": 10, "command_hz": 1}


def run_against(shim, fake, seconds=0.6, robot=None, fish=None):
    """Ticks a behaviour against `fake` for `seconds`: its actions per tick and the longest."""
    b = behaviour(shim, fake.port)
    robot = robot or Agent(4, (50.0, 50.0), (1.0, 0.0))
    fish = [Agent(1, (40.0, 40.0), (1.0, 0.0))] if fish is None else fish
    b.activate(robot, None)
    try:
        log, longest = ticks(b, seconds, robot, fish)
    finally:
        fake.close()
    return b, log, longest


@pytest.mark.parametrize("count", ["abc", None, 1e999, 0, 17, True, 2.5])
def test_a_welcome_with_a_bad_fish_count_halts_with_the_reason(rt, count):
    shim, _ = rt
    b, log, _ = run_against(shim, FakeBridge(dict(WELCOME, fish_count=count)))
    assert b.state == "halted", b.state
    assert "fish_count" in b.reason, b.reason
    assert all(kinds(x) in (["RobotActionFlush", "RobotActionHalt"], []) for x in log)


@pytest.mark.parametrize("line, why", [
    (b"[" * 20_000 + b"]" * 20_000 + b"\n", "RecursionError"),
    (b"x" * 70_000, "bytes"),
    (b'{"type": "command", "turn": true, "stop": false}\n', "turn True"),
    (b'{"type": "command", "turn": "0.5", "stop": false}\n', "turn '0.5'"),
    (b'{"type": "command", "turn": 1e999, "stop": false}\n', "turn inf"),
    (b"[1, 2]\n", "not a JSON object"),
])
def test_a_bridge_sending_garbage_halts_the_behaviour_with_the_reason(rt, line, why):
    shim, _ = rt
    b, log, longest = run_against(shim, FakeBridge(WELCOME, line))
    assert b.state == "halted", (b.state, b.reason)
    assert why in b.reason, b.reason
    assert not any("RobotActionToTarget" in kinds(x) for x in log)
    assert longest < 0.1


def test_a_bridge_that_streams_without_end_never_holds_a_tick(rt):
    shim, _ = rt
    command = b'{"type": "command", "turn": 0.1, "stop": false}\n' * 2000
    b, log, longest = run_against(shim, FakeBridge(WELCOME, command, stream=True))
    assert longest < 0.1, f"a tick took {longest:.3f} s"
    assert b.state == "halted" and "within one tick" in b.reason, b.reason
    assert len(b.inbox) == 0  # closed, nothing buffered


def test_agents_that_are_not_poses_are_untracked_or_halt_with_the_reason(rt):
    shim, _ = rt
    frames = shim.Frames(dict(shim.DEFAULTS))
    for position in ((10 ** 400, 1.0), "12", (True, 1.0), (1.0,), (1.0, 2.0, 3.0), None,
                     (float("inf"), 0.0)):
        assert frames.pose(Agent(1, position, (1.0, 0.0))) is None, position
    assert frames.pose(Agent(1, (1, 2.0), (0.0, 1.0))) is not None
    # A fish list that is not a list: the behaviour halts and says why, RoboTracker sees no
    # exception.
    b, log, _ = run_against(shim, FakeBridge(WELCOME), fish=5)
    assert b.state == "halted" and "TypeError" in b.reason, b.reason
    assert kinds(log[-1]) == []
