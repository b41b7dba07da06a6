"""fishprobe_robotracker: a RoboTracker behaviour through which `fishprobe live serve` drives the
robot. Standard library only; copy this one file into RoboTracker's behaviour folder.

RoboTracker calls `next_speeds` every tracking tick. The behaviour sends that tick's robot and
fish to the bridge as a `frame` of the live protocol (docs/live-protocol.md, `source: "lab"`)
and reads the bridge's `command` messages without ever waiting for them. A command's relative
`turn` becomes a target point `L` ahead in the new direction,

    target = robot position + L * (cos(heading + turn), sin(heading + turn)),

handed to RoboTracker's own controller with `RobotActionToTarget` (after a `RobotActionFlush`).
A `stop` command, any socket error, a bridge that closes, the trial's end and `deactivate` give
`RobotActionFlush` + `RobotActionHalt`, and the robot stays halted until the behaviour is
activated again. One activation is one trial.

Settings: the defaults below, replaced key by key by a JSON file named by the environment
variable FISHPROBE_ROBOTRACKER_SETTINGS, or else `fishprobe_robotracker.json` beside this file
(an unknown key or a wrong value is refused: the robot stays halted and the log says why). The
log goes to the logger "fishprobe_robotracker" (RoboTracker's log), and also to `log_file` when
that is set.
"""

from __future__ import annotations

import json
import logging
import math
import numbers
import os
import socket
import time

try:
    from robotracker import (  # type: ignore[import-not-found]
        PythonBehavior,
        RobotActionFlush,
        RobotActionHalt,
        RobotActionToTarget,
    )
except ImportError:  # outside RoboTracker (documentation, syntax checks): a plain base class

    class PythonBehavior:  # type: ignore[no-redef]
        def __init__(self):
            pass

    RobotActionFlush = RobotActionHalt = RobotActionToTarget = None  # type: ignore[assignment]


LOG = logging.getLogger("fishprobe_robotracker")

# The distance fishprobe's simulated robot covers in one action (one second of the paper's
# 1 Hz commands) when it keeps its heading: 13.6 cm with the robot settings' defaults (at most
# 15 cm/s, through the actuators' lag and acceleration limit). A test of fishprobe
# (crates/cli/tests/live.rs) simulates the robot and fails when this number and the
# simulator part. A target this far ahead asks RoboTracker's controller for the step the
# policy was trained with; if the rig's robot is slower or faster, set `step_cm` to what it
# covers in a second.
SIMULATED_STEP_CM = 13.6

DEFAULTS = {
    # The bridge (`fishprobe live serve`): address, and its --token when it listens off loopback.
    "host": "127.0.0.1",
    "port": 4500,
    "token": None,
    # What the hello declares: RoboTracker's tracking rate (ticks per second).
    "tracking_hz": 25,
    # The robot to drive, by RoboTracker uid; null drives the first robot it lists.
    "robot_uid": None,
    # L: how far ahead the target point of a turn lies (cm).
    "step_cm": SIMULATED_STEP_CM,
    # RoboTracker's frame to fishprobe's (cm, origin at the tank centre, x right, y up):
    # fishprobe x = (x - origin_cm[0]) * (-1 if flip_x else 1), the same for y. A rig whose
    # origin is the top-left corner with y pointing down has origin_cm [50, 50], flip_y true.
    "origin_cm": [0.0, 0.0],
    "flip_x": False,
    "flip_y": False,
    # Seconds to wait for the bridge's welcome after connecting (activation only; the robot is
    # halted meanwhile). While no trial has started, a refused connection is retried every
    # `retry_s` seconds.
    "welcome_timeout_s": 2.0,
    "retry_s": 1.0,
    # Bytes of unsent frames at most (a bridge that stopped reading): past it the trial is
    # given up and the robot halted.
    "max_unsent_bytes": 262144,
    # A file to log to as well (RoboTracker's own log otherwise only).
    "log_file": None,
}

# The longest line the bridge sends is far below this (its own limit for what it reads is the
# same); a longer one is a broken peer.
MAX_LINE_BYTES = 1 << 16

# What one tick reads from the bridge at most: the bridge sends a few hundred bytes a tick, so
# a bridge that streams without end costs a tick no more than this, and the rest waits.
READ_PER_TICK_BYTES = 1 << 16

# Fish a welcome may announce (the bridge's own limit).
MAX_FISH = 16


class SettingsError(ValueError):
    """A settings file with an unknown key or a wrong value."""


def load_settings(path: str | None = None) -> dict:
    """The defaults, replaced key by key by the settings file (see the module's docs)."""
    settings = dict(DEFAULTS)
    if path is None:
        path = os.environ.get("FISHPROBE_ROBOTRACKER_SETTINGS")
        if path is None:
            beside = os.path.join(os.path.dirname(os.path.abspath(__file__)),
                                  "fishprobe_robotracker.json")
            path = beside if os.path.exists(beside) else None
    if path is not None:
        try:
            with open(path, encoding="utf-8") as f:
                given = json.load(f)
        except (OSError, ValueError) as e:
            raise SettingsError(f"cannot read the settings file {path}: {e}") from None
        if not isinstance(given, dict):
            raise SettingsError(f"{path}: the settings must be a JSON object")
        unknown = sorted(set(given) - set(DEFAULTS))
        if unknown:
            raise SettingsError(f"{path}: unknown settings {unknown}; known: {sorted(DEFAULTS)}")
        settings.update(given)
    check_settings(settings)
    return settings


def check_settings(s: dict) -> None:
    def number(key, low, high):
        v = s[key]
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not (low < v <= high):
            raise SettingsError(f"{key} must be a number in ({low}, {high}], got {v!r}")

    if not isinstance(s["host"], str) or not s["host"]:
        raise SettingsError(f"host must be a host name or address, got {s['host']!r}")
    if isinstance(s["port"], bool) or not isinstance(s["port"], int) or not 0 < s["port"] < 65536:
        raise SettingsError(f"port must be a whole number in [1, 65535], got {s['port']!r}")
    if s["token"] is not None and not isinstance(s["token"], str):
        raise SettingsError("token must be a string or null")
    number("tracking_hz", 0, 1000)
    number("step_cm", 0, 100)
    number("welcome_timeout_s", 0, 60)
    number("retry_s", 0, 3600)
    number("max_unsent_bytes", 0, 1 << 30)
    origin = s["origin_cm"]
    if (not isinstance(origin, (list, tuple)) or len(origin) != 2
            or not all(isinstance(v, (int, float)) and not isinstance(v, bool)
                       and math.isfinite(v) for v in origin)):
        raise SettingsError(f"origin_cm must be two finite numbers, got {origin!r}")
    for key in ("flip_x", "flip_y"):
        if not isinstance(s[key], bool):
            raise SettingsError(f"{key} must be true or false, got {s[key]!r}")
    if s["log_file"] is not None and not isinstance(s["log_file"], str):
        raise SettingsError("log_file must be a path or null")


class Frames:
    """RoboTracker's frame <-> fishprobe's (see `origin_cm`, `flip_x`, `flip_y`)."""

    def __init__(self, settings: dict):
        self.ox, self.oy = (float(v) for v in settings["origin_cm"])
        self.sx = -1.0 if settings["flip_x"] else 1.0
        self.sy = -1.0 if settings["flip_y"] else 1.0

    def pose(self, agent) -> dict | None:
        """An agent's pose in fishprobe's frame, or None when it is not tracked (no position or
        orientation, or not two finite numbers each: a string, a boolean, a number too large
        for a float are not)."""
        try:
            px, py = two_numbers(agent.position)
            dx, dy = two_numbers(agent.orientation)
        except (AttributeError, TypeError, ValueError, OverflowError):
            return None
        if not all(math.isfinite(v) for v in (px, py, dx, dy)) or (dx == 0.0 and dy == 0.0):
            return None
        return {"x": (px - self.ox) * self.sx, "y": (py - self.oy) * self.sy,
                "heading": math.atan2(dy * self.sy, dx * self.sx)}

    def to_robotracker(self, x: float, y: float) -> tuple[float, float]:
        return (x * self.sx + self.ox, y * self.sy + self.oy)


def two_numbers(value) -> tuple[float, float]:
    """`value` as two floats; raises unless it is a sequence of exactly two real numbers."""
    if isinstance(value, (str, bytes)):
        raise TypeError("a string is not a position")
    items = list(value)
    if len(items) != 2:
        raise ValueError(f"{len(items)} values, not 2")
    for v in items:
        if isinstance(v, bool) or not isinstance(v, numbers.Real):
            raise TypeError(f"{v!r} is not a number")
    return float(items[0]), float(items[1])


def target_point(pose: dict, turn: float, step_cm: float) -> tuple[float, float]:
    """Where a turn points: `step_cm` ahead of the robot in its new direction (fishprobe's
    frame)."""
    h = pose["heading"] + turn
    return (pose["x"] + step_cm * math.cos(h), pose["y"] + step_cm * math.sin(h))


class Behavior(PythonBehavior):
    """The RoboTracker behaviour (see the module's docs)."""

    def __init__(self, layout=None, settings: dict | None = None):
        PythonBehavior.__init__(self)
        self.problem = None
        try:
            self.settings = settings if settings is not None else load_settings()
            if settings is not None:
                check_settings(self.settings)
        except SettingsError as e:
            self.settings = dict(DEFAULTS)
            self.problem = str(e)
            LOG.error("fishprobe: %s; the robot stays halted", e)
        if self.settings["log_file"]:
            handler = logging.FileHandler(self.settings["log_file"], encoding="utf-8")
            handler.setFormatter(logging.Formatter("%(asctime)s %(levelname)s %(message)s"))
            LOG.addHandler(handler)
            LOG.setLevel(logging.INFO)
        self.frames = Frames(self.settings)
        self.sock = None
        self.state = "idle"  # idle, connecting, running, halted
        self.reason = None
        self.uid = None
        self.fish_count = 1
        self.t0 = None
        self.last_t = -math.inf
        self.next_try = 0.0
        self.inbox = b""
        self.outbox = b""
        self.robot_pose = None
        self.last_command = None

    # -- RoboTracker's interface ------------------------------------------------------------

    def supported_timesteps(self):
        return []

    def activate(self, robot, world):
        try:
            self._activate(robot)
        except Exception as e:  # never raise into RoboTracker: halt and say why
            self.halt(f"activation failed: {type(e).__name__}: {e}")

    def _activate(self, robot):
        self.uid = getattr(robot, "uid", None) if self.settings["robot_uid"] is None \
            else self.settings["robot_uid"]
        self.close()
        self.state = "connecting" if self.problem is None else "halting"
        self.reason = self.problem
        self.t0 = None
        self.last_t = -math.inf
        self.next_try = 0.0
        self.last_command = None
        LOG.info("fishprobe: activated for robot %s", self.uid)

    def deactivate(self):
        try:
            return self._deactivate()
        except Exception as e:  # never raise into RoboTracker: halt and say why
            self.halt(f"deactivation failed: {type(e).__name__}: {e}")
            return []

    def _deactivate(self):
        if self.sock is not None:
            try:
                self.sock.setblocking(True)
                self.sock.settimeout(0.2)
                self.sock.sendall(self.outbox + b'{"type": "end"}\n')
            except OSError:
                pass
        self.halt("deactivated")
        return self.halt_actions()

    def next_speeds(self, robots, fish, timestep):
        try:
            return self._next_speeds(robots, fish)
        except Exception as e:  # never raise into RoboTracker: halt and say why
            self.halt(f"the behaviour failed: {type(e).__name__}: {e}")
            try:
                return self.halt_actions()
            except Exception:
                return []

    def _next_speeds(self, robots, fish):
        robot = self.pick_robot(robots)
        if self.uid is None and robot is not None:
            self.uid = getattr(robot, "uid", None)
        if self.state == "connecting":
            self.try_connect()
            return self.halt_actions()
        if self.state != "running":
            return self.halt_actions() if self.state == "halting" and self.settle() else []
        try:
            self.send_frame(robot, fish)
            actions = self.read_commands()
        except (OSError, ValueError) as e:
            self.halt(f"connection to the bridge lost: {e}")
            return self.halt_actions()
        return actions

    # -- the bridge ---------------------------------------------------------------------------

    def try_connect(self):
        now = time.monotonic()
        if now < self.next_try:
            return
        self.next_try = now + float(self.settings["retry_s"])
        s = self.settings
        try:
            sock = socket.create_connection((s["host"], s["port"]),
                                            timeout=float(s["welcome_timeout_s"]))
        except OSError as e:
            LOG.warning("fishprobe: no bridge at %s:%s (%s); retrying, robot halted",
                        s["host"], s["port"], e)
            return
        try:
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            hello = {"type": "hello", "protocol": 1, "world_size_cm": [100, 100],
                     "tracking_hz": s["tracking_hz"], "source": "lab", "token": s["token"]}
            sock.sendall((json.dumps(hello) + "\n").encode("utf-8"))
            welcome = self.read_welcome(sock, float(s["welcome_timeout_s"]))
        except (OSError, ValueError) as e:
            sock.close()
            self.halt(f"the bridge did not welcome us: {e}")
            return
        if welcome.get("type") != "welcome":
            sock.close()
            self.halt(f"the bridge refused the trial: {welcome.get('reason', welcome)}")
            return
        fish_count = welcome.get("fish_count", 1)
        if isinstance(fish_count, bool) or not isinstance(fish_count, int) \
                or not 1 <= fish_count <= MAX_FISH:
            sock.close()
            self.halt(f"the bridge's welcome says fish_count {fish_count!r}, not a whole "
                      f"number in [1, {MAX_FISH}]")
            return
        self.fish_count = fish_count
        sock.setblocking(False)
        self.sock = sock
        self.state = "running"
        self.t0 = time.monotonic()
        LOG.info("fishprobe: trial started with policy %s (weights %s)",
                 welcome.get("policy"), welcome.get("policy_sha256", "none"))

    def read_welcome(self, sock, timeout: float) -> dict:
        deadline = time.monotonic() + timeout
        data = b""
        while b"\n" not in data:
            left = deadline - time.monotonic()
            if left <= 0:
                raise ValueError("no answer in time")
            sock.settimeout(left)
            chunk = sock.recv(4096)
            if not chunk:
                raise ValueError("the bridge closed the connection")
            data += chunk
            if len(data) > MAX_LINE_BYTES:
                raise ValueError("an over-long answer")
        line, _, rest = data.partition(b"\n")
        self.inbox = rest
        answer = json.loads(line)
        if not isinstance(answer, dict):
            raise ValueError("an answer that is not a JSON object")
        return answer

    def send_frame(self, robot, fish):
        t = time.monotonic() - self.t0
        t = max(t, self.last_t + 1e-6)  # the protocol wants time stamps that increase
        self.last_t = t
        self.robot_pose = self.frames.pose(robot) if robot is not None else None
        listed = []
        for k, f in enumerate(list(fish or [])[: self.fish_count]):
            fid = str(getattr(f, "uid", getattr(f, "id", f"fish_{k + 1}")))
            pose = self.frames.pose(f)
            listed.append({"id": fid, **pose} if pose is not None else {"id": fid})
        frame = {"type": "frame", "t": t, "robot": self.robot_pose, "fish": listed}
        self.outbox += (json.dumps(frame) + "\n").encode("utf-8")
        self.flush_outbox()

    def flush_outbox(self):
        while self.outbox:
            try:
                sent = self.sock.send(self.outbox)
            except (BlockingIOError, InterruptedError):
                break
            self.outbox = self.outbox[sent:]
        if len(self.outbox) > self.settings["max_unsent_bytes"]:
            raise ValueError(f"the bridge has not read {len(self.outbox)} bytes of frames")

    def read_commands(self) -> list:
        # One read a tick: a bridge that streams without end cannot hold the tick.
        try:
            chunk = self.sock.recv(READ_PER_TICK_BYTES)
        except (BlockingIOError, InterruptedError):
            chunk = None
        if chunk == b"":
            raise ValueError("the bridge closed the connection")
        if chunk and len(chunk) >= READ_PER_TICK_BYTES:
            # Hundreds of times what a bridge sends: its commands would be stale by now.
            raise ValueError(f"the bridge sent {len(chunk)} bytes or more within one tick")
        if chunk:
            self.inbox += chunk
        partial = len(self.inbox) - (self.inbox.rfind(b"\n") + 1)
        if partial > MAX_LINE_BYTES:
            raise ValueError(f"a line of more than {MAX_LINE_BYTES} bytes from the bridge")
        actions = []
        while b"\n" in self.inbox:
            line, _, self.inbox = self.inbox.partition(b"\n")
            if not line.strip():
                continue
            msg = json.loads(line)
            if not isinstance(msg, dict):
                raise ValueError("a message that is not a JSON object")
            actions = self.handle(msg, actions)
            if self.state != "running":
                return actions
        return actions

    def handle(self, msg: dict, actions: list) -> list:
        kind = msg.get("type")
        if kind == "command":
            self.last_command = msg
            if msg.get("stop"):
                LOG.warning("fishprobe: stop (%s)", msg.get("reason", "no reason given"))
                return self.halt_actions()
            turn = msg.get("turn")
            if isinstance(turn, bool) or not isinstance(turn, (int, float)) \
                    or not math.isfinite(turn):
                self.halt(f"the bridge sent a command with turn {turn!r}, not a finite number")
                return self.halt_actions()
            if self.robot_pose is None:
                return self.halt_actions()
            x, y = target_point(self.robot_pose, float(turn), float(self.settings["step_cm"]))
            tx, ty = self.frames.to_robotracker(x, y)
            return [RobotActionFlush(self.uid), RobotActionToTarget(self.uid, 0, (tx, ty))]
        if kind == "error":
            LOG.error("fishprobe: the bridge says: %s", msg.get("reason"))
        elif kind == "done":
            LOG.info("fishprobe: trial done, %s goals, file %s", msg.get("goals_reached"),
                     msg.get("file"))
            self.halt("the trial is done")
            return self.halt_actions()
        return actions

    # -- stopping -------------------------------------------------------------------------------

    def halt(self, reason: str):
        if self.state not in ("halted", "halting"):
            LOG.warning("fishprobe: robot halted: %s", reason)
            self.reason = reason
        self.close()
        self.state = "halting"

    def settle(self) -> bool:
        """After a halt: the flush + halt is returned once more on the next tick, then the
        behaviour is quiet until activated again."""
        self.state = "halted"
        return True

    def halt_actions(self) -> list:
        if self.uid is None:
            return []
        return [RobotActionFlush(self.uid), RobotActionHalt(self.uid, 0)]

    def close(self):
        if self.sock is not None:
            try:
                self.sock.close()
            except OSError:
                pass
        self.sock = None
        self.inbox = b""
        self.outbox = b""

    def pick_robot(self, robots):
        robots = list(robots or [])
        if not robots:
            return None
        if self.uid is None:
            return robots[0]
        for r in robots:
            if getattr(r, "uid", None) == self.uid:
                return r
        return None
