//! One live trial as a state machine, free of sockets: tracking frames in, robot commands out,
//! and at the end the trial file. Decisions use the tracking time stamps only, so the same
//! session runs at real time with the lab and faster than real time with the virtual lab.

use crate::track::{Command, Frame, Phase, Pose};
use fishprobe_io::{Attr, Category, Entity, TaskRecord, TrialFile, TrialKind};
use fishprobe_sim::params::{check, ConfigError};
use fishprobe_sim::{
    stream, wrap_angle, AgentState, ControlInput, Controller, GoalTracker, ObservationEncoder,
    ObservationParams, Scene, SimRng, Tank, TankParams, TaskMode, TaskParams,
};
use std::collections::BTreeMap;

fishprobe_sim::documented_params! {
    /// The trial protocol of SPEC §4 and the bridge's safety settings.
    pub struct LiveConfig {
        /// Habituation: the robot mills in the centre (paper: 2 min).
        pub habituation_s: f64 = 120.0; "s",
        /// The fish is released from its container this long after the start (paper: 1 min).
        pub release_s: f64 = 60.0; "s",
        /// Closed-loop control after habituation (paper: 15 min).
        pub control_s: f64 = 900.0; "s",
        /// Policy commands per second of tracking time (paper: 1 Hz); at most 100, and at
        /// least one command period within `control_s`.
        pub command_hz: f64 = 1.0; "Hz",
        /// Tracking of robot or fish missing for this long: stop the robot (choice).
        pub stale_s: f64 = 0.5; "s",
        /// Radius of the robot's milling circle during habituation (choice); at most half
        /// the tank's side.
        pub mill_radius_cm: f32 = 15.0; "cm",
        /// Rate at which frames are stored in the trial file (the tracking rate, 25 Hz).
        pub file_rate_hz: f32 = 25.0; "Hz",
        /// Longest accepted message (bytes); longer lines are dropped and the robot stopped.
        pub max_message_bytes: usize = 65_536; "bytes",
        /// Fish in the tank (1 to 16; paper: 1). Each frame lists them in a fixed order; a
        /// fish missing from the list or with a null pose is untracked in that frame. The
        /// robot stops when it or every fish is untracked for `stale_s` (choice: in a group
        /// fish hide behind each other, so one tracked fish suffices).
        pub fish_count: u32 = 1; "1",
        /// The policy's observation has the group centroid's bins (216 values; see
        /// `observation.centroid_bins` of the environment settings; choice: off, the paper's
        /// 180). Must match how the policy was trained.
        pub centroid_bins: bool = false; "-",
        /// The policy's observation has the fish's headings' bins (`observation.heading_bins`
        /// of the environment settings, for the OOD task; choice: off, the paper's
        /// observation), from the headings of the tracker's frames. Must match how the policy
        /// was trained.
        pub heading_bins: bool = false; "-",
        /// A running trial is written to its file this often (s of trial time; choice: 2 s,
        /// so a kill that cannot be caught, or a power cut, loses at most 2 s; the write, at
        /// most a MB for a whole trial, runs beside the trial); the trial's end replaces the
        /// file.
        pub checkpoint_s: f64 = 2.0; "s",
    }
}

/// Most policy commands per second (`command_hz`): 100, a hundred times the paper's 1 Hz.
pub const MAX_COMMAND_HZ: f64 = 100.0;

/// Largest `max_message_bytes` accepted: 16 MiB, thousands of times a frame of 16 fish
/// (under 2 kB); the bridge holds one line of at most this size per connection.
pub const MAX_MESSAGE_BYTES: usize = 1 << 24;

impl LiveConfig {
    /// The observation the policy gets from the tracker's frames under these settings (the
    /// environment's, with the centroid's and headings' blocks as set here).
    pub fn observation(&self) -> fishprobe_sim::ObservationParams {
        fishprobe_sim::ObservationParams {
            centroid_bins: self.centroid_bins,
            heading_bins: self.heading_bins,
            ..fishprobe_sim::ObservationParams::default()
        }
    }

    /// Checks the ranges.
    pub fn validate(&self) -> Result<(), ConfigError> {
        let day = f64::from(check::MAX_DURATION_S);
        for (f, v, hi) in [
            ("habituation_s", self.habituation_s, day),
            ("control_s", self.control_s, day),
            ("stale_s", self.stale_s, day),
            ("command_hz", self.command_hz, MAX_COMMAND_HZ),
            ("checkpoint_s", self.checkpoint_s, day),
        ] {
            if !(v.is_finite() && v > 0.0 && v <= hi) {
                return Err(ConfigError::new(
                    "live",
                    f,
                    check::shown(v),
                    &format!("must lie in (0, {}]", check::shown(hi)),
                ));
            }
        }
        if self.habituation_s + self.control_s > day {
            return Err(ConfigError::new(
                "live",
                "control_s",
                check::shown(self.control_s),
                &format!(
                    "with habituation_s = {} makes a trial longer than {} s (a day)",
                    check::shown(self.habituation_s),
                    check::shown(day)
                ),
            ));
        }
        // A rate so low that no command period ends within the control phase would leave
        // the robot with its first command for the whole trial: a typo, not a protocol.
        if self.command_hz * self.control_s < 1.0 {
            return Err(ConfigError::new(
                "live",
                "command_hz",
                check::shown(self.command_hz),
                &format!(
                    "gives no second command within control_s = {} s (at least 1 / control_s)",
                    check::shown(self.control_s)
                ),
            ));
        }
        if !(self.release_s >= 0.0 && self.release_s <= self.habituation_s) {
            return Err(ConfigError::new(
                "live",
                "release_s",
                check::shown(self.release_s),
                &format!(
                    "must lie within the habituation, [0, habituation_s = {}]",
                    check::shown(self.habituation_s)
                ),
            ));
        }
        if !(1..=fishprobe_sim::MAX_FISH as u32).contains(&self.fish_count) {
            return Err(ConfigError::new(
                "live",
                "fish_count",
                self.fish_count,
                &format!("must lie in [1, {}]", fishprobe_sim::MAX_FISH),
            ));
        }
        // Beyond half the tank's side the robot would mill into the walls.
        check::positive_at_most(
            "live",
            "mill_radius_cm",
            self.mill_radius_cm,
            crate::TANK_CM / 2.0,
        )?;
        // The trial file holds every frame of the trial in memory until it is written, so
        // the rate bounds what a peer's time stamps can make the bridge store.
        check::positive_at_most(
            "live",
            "file_rate_hz",
            self.file_rate_hz,
            fishprobe_sim::env::MAX_FRAME_RATE_HZ,
        )?;
        if !(256..=MAX_MESSAGE_BYTES).contains(&self.max_message_bytes) {
            return Err(ConfigError::new(
                "live",
                "max_message_bytes",
                self.max_message_bytes,
                &format!("must lie in [256, {MAX_MESSAGE_BYTES}]"),
            ));
        }
        Ok(())
    }
}

/// A stop the bridge ordered.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct StopEvent {
    /// File frame at which it was ordered.
    pub frame: u64,
    /// Why.
    pub reason: String,
}

/// One trial in progress.
pub struct Session {
    cfg: LiveConfig,
    task: TaskParams,
    pilot: Box<dyn Controller>,
    /// The controller's action stream (a policy's mean action does not use it).
    rng: SimRng,
    kind: TrialKind,
    tank: Tank,
    encoder: ObservationEncoder,
    prev: Vec<f32>,
    first_obs: bool,
    obs: Vec<f32>,
    goals: GoalTracker,
    t0: Option<f64>,
    last_t: f64,
    next_seq: u64,
    last_good: Option<f64>,
    last_robot: Option<Pose>,
    /// Per fish, its last tracked pose.
    last_fish: Vec<Option<Pose>>,
    /// Which entry of a frame is which fish (by the tracker's ids).
    fish_ids: crate::fish_ids::FishIds,
    stopped: Option<String>,
    robot: Vec<[f32; 3]>,
    /// Per fish, its pose per stored frame.
    fish: Vec<Vec<[f32; 3]>>,
    active: Vec<i32>,
    goal_frames: Vec<u64>,
    command_frames: Vec<u64>,
    command_turns: Vec<f32>,
    stops: Vec<StopEvent>,
    gaps: Vec<[u64; 2]>,
    malformed: u64,
    goals_reached: u32,
    accepted: u64,
    /// Set when the pilot failed (a non-finite turn): the robot stays stopped for the rest of
    /// the trial, since good tracking does not mend a broken policy.
    pilot_fault: Option<String>,
    /// What the front end adds to the trial file's record (see [`Session::note`]).
    notes: serde_json::Map<String, serde_json::Value>,
    /// Frames stored when the last checkpoint was written.
    checkpointed_frames: usize,
}

impl std::fmt::Debug for Session {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Session")
            .field("pilot", &self.pilot.name())
            .field("frames", &self.robot.len())
            .field("goals_reached", &self.goals_reached)
            .finish()
    }
}

const LOST: [f32; 3] = [f32::NAN; 3];

impl Session {
    /// A session of a trial of `kind` (real, or the virtual lab's).
    pub fn new(
        cfg: LiveConfig,
        task: TaskParams,
        pilot: Box<dyn Controller>,
        kind: TrialKind,
    ) -> Result<Self, ConfigError> {
        cfg.validate()?;
        let tank = Tank::new(&TankParams::default());
        let encoder = ObservationEncoder::new(&ObservationParams {
            centroid_bins: cfg.centroid_bins,
            heading_bins: cfg.heading_bins,
            ..ObservationParams::default()
        });
        let n = encoder.size();
        let mut rng = stream(0, "live-goals", 0);
        let goals = GoalTracker::start(TaskMode::Evaluation, &task, &tank, &[], &mut rng);
        let n_fish = cfg.fish_count as usize;
        Ok(Self {
            kind,
            cfg,
            task,
            pilot,
            rng: stream(0, "live-actions", 0),
            tank,
            prev: vec![0.0; encoder.history_len()],
            obs: vec![0.0; n],
            encoder,
            first_obs: true,
            goals,
            t0: None,
            last_t: f64::NEG_INFINITY,
            next_seq: 0,
            last_good: None,
            last_robot: None,
            last_fish: vec![None; n_fish],
            fish_ids: crate::fish_ids::FishIds::new(n_fish),
            stopped: None,
            robot: Vec::new(),
            fish: vec![Vec::new(); n_fish],
            active: Vec::new(),
            goal_frames: Vec::new(),
            command_frames: Vec::new(),
            command_turns: Vec::new(),
            stops: Vec::new(),
            gaps: Vec::new(),
            malformed: 0,
            goals_reached: 0,
            accepted: 0,
            pilot_fault: None,
            notes: serde_json::Map::new(),
            checkpointed_frames: 0,
        })
    }

    /// Trial kind (real or virtual).
    pub fn kind(&self) -> TrialKind {
        self.kind
    }

    /// The pilot's name.
    pub fn policy(&self) -> String {
        self.pilot.name()
    }

    /// The SHA-256 of the pilot's weights (none for a scripted pilot), as its trial records it.
    pub fn fingerprint(&self) -> Option<String> {
        self.pilot.fingerprint()
    }

    /// Goals reached so far.
    pub fn goals_reached(&self) -> u32 {
        self.goals_reached
    }

    /// Sets the trial's time zero, before its first frame (by default the first frame's time
    /// is). A tracker that numbers a recording's frames from 0 may deliver frame 1 or later
    /// first; with its frame 0 as time zero, the trial file's frame k is the recording's frame
    /// k and the frames before the first delivered are tracking gaps (NaN), as frames the
    /// tracker skips are. Ignored once a frame was accepted, and for a time that is not finite.
    pub fn set_origin(&mut self, t0: f64) {
        if self.accepted == 0 && t0.is_finite() {
            self.t0 = Some(t0);
        }
    }

    /// Frames stored so far.
    pub fn frames(&self) -> usize {
        self.robot.len()
    }

    /// Tracking frames accepted so far (well-formed, with a time stamp after the last one):
    /// the only sign of life the bridge's silence stop counts.
    pub fn frames_accepted(&self) -> u64 {
        self.accepted
    }

    /// Stops ordered so far.
    pub fn stops(&self) -> &[StopEvent] {
        &self.stops
    }

    /// Records `value` under `key` in the trial file's record (its `config_json`, under
    /// `"front_end"`): what the front end knows and the session does not (the tracker's
    /// rate, updates it dropped, why the trial ended). A later note under the same key
    /// replaces the earlier one.
    pub fn note(&mut self, key: &str, value: serde_json::Value) {
        self.notes.insert(key.to_string(), value);
    }

    fn rel(&self, t: f64) -> f64 {
        t - self.t0.unwrap_or(t)
    }

    fn phase_at(&self, rel: f64) -> Phase {
        if rel < self.cfg.habituation_s {
            Phase::Habituation
        } else if rel < self.cfg.habituation_s + self.cfg.control_s {
            Phase::Control
        } else {
            Phase::Done
        }
    }

    /// Whether the trial is complete.
    pub fn is_done(&self) -> bool {
        self.t0.is_some() && self.phase_at(self.rel(self.last_t)) == Phase::Done
    }

    fn frame_index(&self, t: f64) -> u64 {
        (self.rel(t) * f64::from(self.cfg.file_rate_hz))
            .round()
            .max(0.0) as u64
    }

    fn command(&self, t: f64, seq: Option<u64>, turn: f32, phase: Phase) -> Command {
        let rel = self.rel(t);
        Command {
            t,
            seq,
            turn,
            stop: self.stopped.is_some(),
            reason: self.stopped.clone(),
            phase,
            released: rel >= self.cfg.release_s,
            active_goal: (phase == Phase::Control).then_some(self.goals.active),
            goals_reached: self.goals_reached,
        }
    }

    /// Marks the robot stopped (recording why); false when it already was.
    fn mark_stopped(&mut self, t: f64, reason: String) -> bool {
        if self.stopped.is_some() {
            return false;
        }
        self.stopped = Some(reason.clone());
        let frame = self.frame_index(t);
        self.stops.push(StopEvent { frame, reason });
        true
    }

    fn stop(&mut self, t: f64, reason: String, out: &mut Vec<Command>) {
        if self.mark_stopped(t, reason) {
            let phase = self.phase_at(self.rel(t));
            out.push(self.command(t, None, 0.0, phase));
        }
    }

    /// A line that could not be used: stop the robot and say why.
    pub fn on_malformed(&mut self, reason: &str) -> Vec<Command> {
        self.malformed += 1;
        let mut out = Vec::new();
        let t = if self.last_t.is_finite() {
            self.last_t
        } else {
            0.0
        };
        self.stop(t, format!("malformed input: {reason}"), &mut out);
        // A later good frame lifts a stop for malformed input like any other.
        out
    }

    /// The time stamp of the last frame taken (0 before the first).
    pub fn last_time(&self) -> f64 {
        if self.last_t.is_finite() {
            self.last_t
        } else {
            0.0
        }
    }

    /// The trial ends before its time (fishprobe was asked to stop, say): the robot is
    /// stopped with `reason`, which the trial file records as why it ended; returns the stop
    /// command for the robot side.
    pub fn end_early(&mut self, reason: &str) -> Command {
        let t = self.last_time();
        self.note("ended_because", reason.into());
        Command::stop_outside_trial(t, reason, self.goals_reached)
    }

    /// No frame for `silence_s` of wall-clock time (the lab's tracker hangs): stop.
    pub fn on_silence(&mut self, silence_s: f64) -> Vec<Command> {
        let mut out = Vec::new();
        if silence_s >= self.cfg.stale_s && self.t0.is_some() {
            let t = self.last_t;
            self.stop(
                t,
                format!("no tracking frame for {silence_s:.2} s"),
                &mut out,
            );
        }
        out
    }

    /// One tracked frame; returns the commands for the robot.
    pub fn on_frame(&mut self, frame: &Frame) -> Vec<Command> {
        let (t, robot, fish) = (frame.t, frame.robot, frame.fish.as_slice());
        let mut out = Vec::new();
        if !t.is_finite() || t <= self.last_t {
            return self.on_malformed(&format!("time stamp {t} not after {}", self.last_t));
        }
        if self.t0.is_none() {
            self.t0 = Some(t);
        }
        self.last_t = t;
        self.accepted += 1;
        let rel = self.rel(t);
        let phase = self.phase_at(rel);
        if phase == Phase::Done {
            return out;
        }
        let robot = robot.filter(Pose::is_valid);
        // The fish matched by the tracker's ids (see `fish_ids`), whatever their order.
        let k = self.frame_index(t) as usize;
        let fish_poses = self.fish_ids.assign(k as u64, fish);
        let any_fish = fish_poses.iter().any(Option::is_some);
        // The fish count from their release on; before, only the robot must be tracked.
        let need_fish = rel >= self.cfg.release_s;
        let good = robot.is_some() && (any_fish || !need_fish);
        if let Some(r) = robot {
            self.last_robot = Some(r);
        }
        for (last, now) in self.last_fish.iter_mut().zip(&fish_poses) {
            if now.is_some() {
                *last = *now;
            }
        }
        // Store the frame (gaps as NaN; frames skipped by the tracker as NaN too).
        while self.robot.len() < k {
            self.robot.push(LOST);
            for f in &mut self.fish {
                f.push(LOST);
            }
            self.active.push(self.active.last().copied().unwrap_or(0));
        }
        if self.robot.len() == k {
            let p = |x: Option<Pose>| x.map_or(LOST, |p| [p.x, p.y, p.heading]);
            self.robot.push(p(robot));
            for (f, now) in self.fish.iter_mut().zip(&fish_poses) {
                f.push(p(*now));
            }
            self.active.push(self.goals.index as i32);
        }
        // Safety.
        if good {
            if let Some(g) = self.last_good {
                if t - g >= self.cfg.stale_s {
                    self.gaps.push([self.frame_index(g), self.frame_index(t)]);
                }
            }
            self.last_good = Some(t);
            if self.pilot_fault.is_none() {
                self.stopped = None;
            }
        } else {
            let since = self.last_good.unwrap_or(self.t0.unwrap_or(t));
            if t - since >= self.cfg.stale_s {
                let what = if robot.is_none() { "robot" } else { "fish" };
                self.stop(
                    t,
                    format!("{what} not tracked for {:.2} s", t - since),
                    &mut out,
                );
            }
        }
        // Goals, during control, on every frame with a tracked fish (a group by
        // `task.group_goal`, over the fish tracked in this frame).
        if phase == Phase::Control && any_fish {
            let mut rng = stream(0, "live-goals", 0);
            let me: Vec<AgentState> = fish_poses
                .iter()
                .flatten()
                .map(|f| AgentState::at(f.x, f.y, f.heading))
                .collect();
            if self
                .goals
                .check(TaskMode::Evaluation, &self.task, &self.tank, &me, &mut rng)
                .is_some()
            {
                self.goals_reached += 1;
                self.goal_frames.push(k as u64);
                if let Some(a) = self.active.last_mut() {
                    *a = self.goals.index as i32;
                }
            }
        }
        // The scheduled command.
        let due = self.next_seq as f64 / self.cfg.command_hz;
        if rel + 1e-9 >= due {
            let seq = self.next_seq;
            self.next_seq += 1;
            let mut turn = if self.stopped.is_some() {
                0.0
            } else {
                match phase {
                    Phase::Habituation => self.mill_turn(),
                    Phase::Control => self.policy_turn(),
                    Phase::Done => 0.0,
                }
            };
            if !turn.is_finite() {
                // A policy that outputs NaN or infinity never drives the robot.
                let reason = format!(
                    "the policy produced a non-finite turn ({turn}) at {:.2} s; the robot stays \
                     stopped for the rest of the trial",
                    rel
                );
                self.pilot_fault = Some(reason.clone());
                self.mark_stopped(t, reason);
                turn = 0.0;
            }
            if phase == Phase::Control && self.stopped.is_none() {
                self.command_frames.push(k as u64);
                self.command_turns.push(turn);
            }
            out.push(self.command(t, Some(seq), turn, phase));
        }
        out
    }

    /// Milling: head for a point 0.5 rad ahead on the circle around the centre.
    fn mill_turn(&self) -> f32 {
        let Some(r) = self.last_robot else { return 0.0 };
        let phi = r.y.atan2(r.x) + 0.5;
        let (tx, ty) = (
            self.cfg.mill_radius_cm * phi.cos(),
            self.cfg.mill_radius_cm * phi.sin(),
        );
        wrap_angle((ty - r.y).atan2(tx - r.x) - r.heading)
    }

    fn policy_turn(&mut self) -> f32 {
        // Every fish where it was last seen (a fish never seen yet is left out).
        let fish: Vec<AgentState> = self
            .last_fish
            .iter()
            .flatten()
            .map(|f| AgentState::at(f.x, f.y, f.heading))
            .collect();
        let Some(r) = self.last_robot else {
            return 0.0;
        };
        if fish.is_empty() {
            return 0.0;
        }
        let robot = AgentState::at(r.x, r.y, r.heading);
        let scene = Scene {
            tank: &self.tank,
            robot: &robot,
            fish: &fish,
            goal: self.goals.active,
        };
        self.encoder
            .encode(scene, &mut self.prev, self.first_obs, &mut self.obs);
        self.first_obs = false;
        // Non-finite turns are returned as they are: the caller stops the robot.
        let input = ControlInput {
            obs: &self.obs,
            robot,
            fish: &fish,
            goal: self.goals.active,
        };
        let turn = self.pilot.act(&input, &mut self.rng);
        if turn.is_finite() {
            turn.clamp(-std::f32::consts::PI, std::f32::consts::PI)
        } else {
            turn
        }
    }

    /// Whether a checkpoint of the running trial is due (every `checkpoint_s` of stored
    /// frames); a `true` counts as written.
    pub fn checkpoint_due(&mut self) -> bool {
        let every = (self.cfg.checkpoint_s * f64::from(self.cfg.file_rate_hz)).max(1.0);
        let due = (self.frames() - self.checkpointed_frames) as f64 >= every;
        if due {
            self.checkpointed_frames = self.frames();
        }
        due
    }

    /// The trial so far as a file whose `ended_because` says it is a checkpoint.
    pub fn checkpoint_file(&self, fish_model: &str) -> TrialFile {
        let mut f = self.trial_file(fish_model);
        if let Some(task) = f.task.as_mut() {
            if let Ok(serde_json::Value::Object(mut config)) =
                serde_json::from_str::<serde_json::Value>(&task.config_json)
            {
                let front = config
                    .entry("front_end")
                    .or_insert_with(|| serde_json::json!({}));
                front["ended_because"] = crate::keep::CHECKPOINT_NOTE.into();
                task.config_json = serde_json::Value::Object(config).to_string();
            }
        }
        f
    }

    /// The trial file of what was recorded (complete up to the last frame).
    pub fn trial_file(&self, fish_model: &str) -> TrialFile {
        let entity = |name: &str, cat: Category, label: &str, poses: &[[f32; 3]]| Entity {
            name: name.into(),
            category: cat,
            category_label: label.into(),
            positions: poses.iter().map(|p| [p[0], p[1]]).collect(),
            orientations: poses
                .iter()
                .map(|p| {
                    if p[2].is_finite() {
                        [p[2].cos(), p[2].sin()]
                    } else {
                        [f32::NAN; 2]
                    }
                })
                .collect(),
            attributes: BTreeMap::new(),
        };
        let mut attributes = BTreeMap::new();
        let setup = match self.kind {
            TrialKind::Virtual => {
                "fishprobe virtual lab through the live bridge (VIRTUAL: not live fish)"
            }
            _ => "fishprobe live bridge: policy-controlled robot with a live fish",
        };
        attributes.insert("experiment_setup".into(), Attr::Text(setup.into()));
        let mut config = serde_json::json!({
            fishprobe_io::POLICY_SHA256_KEY: self.fingerprint(),
            "live": self.cfg,
            "stops": self.stops,
            "tracking_gaps_frames": self.gaps,
            "malformed_messages": self.malformed,
        });
        let ids = &self.fish_ids;
        if !ids.changes().is_empty() || ids.ignored() > 0 || ids.by_order() > 0 {
            config["fish_matching"] = serde_json::json!({
                "id_changes": ids.changes(),
                "entries_ignored": ids.ignored(),
                "frames_matched_by_order": ids.by_order(),
            });
        }
        // Only a front end that has something to say adds the key, so the bridge's and the
        // virtual lab's files stay as they were.
        if !self.notes.is_empty() {
            config["front_end"] = serde_json::Value::Object(self.notes.clone());
        }
        TrialFile {
            world_size_cm: [crate::TANK_CM; 2],
            frame_rate_hz: self.cfg.file_rate_hz,
            entities: std::iter::once(entity("robot", Category::Robot, "robot", &self.robot))
                .chain(self.fish.iter().enumerate().map(|(i, f)| {
                    let mut e = entity(&format!("fish_{}", i + 1), Category::Fish, "fish", f);
                    if let Some(Some(id)) = self.fish_ids.first_ids().get(i) {
                        e.attributes.insert(
                            fishprobe_io::TRACKER_ID_ATTRIBUTE.into(),
                            Attr::Text(id.clone()),
                        );
                    }
                    e
                }))
                .collect(),
            attributes,
            task: Some(TaskRecord {
                kind: self.kind,
                policy: self.pilot.name(),
                fish_model: fish_model.into(),
                seed: 0,
                goal_radius_cm: self.task.goal_radius_cm,
                goals: self.task.evaluation_goals.to_vec(),
                active_goal: self.active.clone(),
                goal_frames: self.goal_frames.clone(),
                command_frames: self.command_frames.clone(),
                command_turns: self.command_turns.clone(),
                control_start_frame: (self.cfg.habituation_s * f64::from(self.cfg.file_rate_hz))
                    .round() as u64,
                config_json: config.to_string(),
                program_version: env!("CARGO_PKG_VERSION").into(),
            }),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::track::FishPose;

    #[derive(Clone)]
    struct Straight;
    impl Controller for Straight {
        fn name(&self) -> String {
            "Straight".into()
        }
        fn act(&mut self, input: &ControlInput<'_>, _rng: &mut SimRng) -> f32 {
            assert_eq!(input.obs.len(), 180);
            0.25
        }
    }

    fn frame(t: f64, robot: Option<(f32, f32)>, fish: Option<(f32, f32)>) -> Frame {
        Frame {
            t,
            robot: robot.map(|(x, y)| Pose { x, y, heading: 0.0 }),
            fish: vec![FishPose {
                id: "f".into(),
                pose: fish.map(|(x, y)| Pose { x, y, heading: 0.0 }),
            }],
        }
    }

    fn short() -> LiveConfig {
        LiveConfig {
            habituation_s: 4.0,
            release_s: 2.0,
            control_s: 6.0,
            ..LiveConfig::default()
        }
    }

    /// A session of the short protocol flown by the straight-ahead pilot.
    fn straight(kind: TrialKind) -> Session {
        Session::new(short(), TaskParams::default(), Box::new(Straight), kind).unwrap()
    }

    #[test]
    fn phases_commands_and_goals_follow_the_time_stamps() {
        let mut s = straight(TrialKind::Virtual);
        let mut scheduled = 0;
        for k in 0..300 {
            let t = 100.0 + f64::from(k) * 0.04;
            // The fish sits in the first goal from t = 6 s on.
            let fish = if k >= 150 {
                (-20.0, -20.0)
            } else {
                (30.0, 30.0)
            };
            for m in s.on_frame(&frame(t, Some((0.0, 0.0)), Some(fish))) {
                if let Command {
                    seq: Some(q),
                    phase,
                    turn,
                    stop,
                    ..
                } = m
                {
                    assert_eq!(q, scheduled);
                    assert!(!stop);
                    let rel = t - 100.0;
                    assert_eq!(phase == Phase::Control, (4.0..10.0).contains(&rel));
                    if phase == Phase::Control {
                        assert_eq!(turn, 0.25);
                    }
                    scheduled += 1;
                }
            }
        }
        assert_eq!(scheduled, 10, "one command per second until the end");
        assert!(s.is_done());
        assert_eq!(s.goals_reached(), 1);
        let f = s.trial_file("Guppy");
        let task = f.task.as_ref().unwrap();
        assert_eq!(task.kind, TrialKind::Virtual);
        assert_eq!(task.control_start_frame, 100);
        assert_eq!(task.goal_frames, vec![150]);
        assert_eq!(task.command_frames.len(), 6);
        assert_eq!(f.entities[0].positions.len(), 250);
    }

    #[test]
    fn a_set_origin_makes_the_first_frame_delivered_the_frame_of_its_time() {
        let mut s = straight(TrialKind::Real);
        s.set_origin(0.0);
        // The recording's frames 2, 3, 4 (0 and 1 never delivered).
        for k in 2..5 {
            let _ = s.on_frame(&frame(
                f64::from(k) * 0.04,
                Some((1.0, k as f32)),
                Some((10.0, 0.0)),
            ));
        }
        // Too late once a frame was accepted: the time zero stays.
        s.set_origin(7.0);
        let _ = s.on_frame(&frame(0.2, Some((1.0, 5.0)), Some((10.0, 0.0))));
        let f = s.trial_file("Guppy");
        let robot = &f.entities[0].positions;
        assert_eq!(robot.len(), 6);
        assert!(robot[0][0].is_nan() && robot[1][0].is_nan());
        for (k, p) in robot.iter().enumerate().skip(2) {
            assert_eq!(*p, [1.0, k as f32], "frame {k}");
        }
    }

    #[test]
    fn lost_tracking_stops_within_one_frame_of_the_timeout_and_resumes() {
        let mut s = straight(TrialKind::Real);
        let mut stop_at = None;
        let mut resumed = false;
        for k in 0..200 {
            let t = f64::from(k) * 0.04;
            let lost = (120..150).contains(&k);
            let msgs = s.on_frame(&frame(t, Some((0.0, 0.0)), (!lost).then_some((10.0, 0.0))));
            for m in msgs {
                let Command { stop, seq, .. } = m;
                if stop && seq.is_none() && stop_at.is_none() {
                    stop_at = Some(k);
                }
                if !stop && k >= 150 {
                    resumed = true;
                }
            }
        }
        // Last good frame 119 (t = 4.76); the stale time 0.5 s is reached at frame 132.
        assert_eq!(stop_at, Some(132));
        assert!(resumed);
        let f = s.trial_file("live");
        assert!(
            f.entities[1].positions[125][0].is_nan(),
            "the gap is recorded as NaN"
        );
        assert!(f.task.unwrap().config_json.contains("not tracked"));
    }

    #[test]
    fn malformed_input_and_time_going_backwards_stop_the_robot() {
        let mut s = straight(TrialKind::Real);
        s.on_frame(&frame(1.0, Some((0.0, 0.0)), Some((1.0, 1.0))));
        let out = s.on_malformed("garbage");
        assert!(matches!(out[0], Command { stop: true, .. }));
        let out = s.on_frame(&frame(0.5, Some((0.0, 0.0)), Some((1.0, 1.0))));
        assert!(out.is_empty(), "already stopped");
        assert_eq!(s.stops().len(), 1);
        assert!(LiveConfig {
            release_s: 500.0,
            ..LiveConfig::default()
        }
        .validate()
        .is_err());
        // A milling circle wider than the tank would mill into the walls.
        let mill = |r: f32| {
            LiveConfig {
                mill_radius_cm: r,
                ..LiveConfig::default()
            }
            .validate()
        };
        assert!(mill(50.0).is_ok());
        let e = mill(50.5).unwrap_err().to_string();
        assert!(
            e.contains("live.mill_radius_cm") && e.contains("(0, 50]"),
            "{e}"
        );
    }

    #[test]
    fn a_file_rate_or_line_length_that_would_let_a_peer_fill_memory_is_refused() {
        let rate = |hz: f32| {
            LiveConfig {
                file_rate_hz: hz,
                ..LiveConfig::default()
            }
            .validate()
        };
        assert!(rate(1000.0).is_ok());
        // 1e30 frames per second: a peer's time stamp one second on made the bridge store
        // frames without end.
        let e = rate(1e30).unwrap_err().to_string();
        assert!(
            e.contains("live.file_rate_hz") && e.contains("(0, 1000]"),
            "{e}"
        );
        let line = |n: usize| {
            LiveConfig {
                max_message_bytes: n,
                ..LiveConfig::default()
            }
            .validate()
        };
        assert!(line(MAX_MESSAGE_BYTES).is_ok());
        let e = line(1 << 40).unwrap_err().to_string();
        assert!(
            e.contains("live.max_message_bytes") && e.contains("[256, 16777216]"),
            "{e}"
        );
        assert!(line(255).is_err());
    }

    #[test]
    fn a_trial_longer_than_a_day_is_refused_naming_the_field_at_fault() {
        let err = |c: LiveConfig| c.validate().unwrap_err().to_string();
        let e = err(LiveConfig {
            habituation_s: 1e30,
            ..LiveConfig::default()
        });
        assert!(
            e.contains("`live.habituation_s` = 1e30: must lie in (0, 86400]"),
            "{e}"
        );
        let e = err(LiveConfig {
            habituation_s: 50_000.0,
            control_s: 50_000.0,
            ..LiveConfig::default()
        });
        assert!(
            e.contains("`live.control_s` = 50000: with habituation_s = 50000"),
            "{e}"
        );
        let e = err(LiveConfig {
            command_hz: 1000.0,
            ..LiveConfig::default()
        });
        assert!(
            e.contains("`live.command_hz` = 1000: must lie in (0, 100]"),
            "{e}"
        );
        let e = err(LiveConfig {
            command_hz: 1e-30,
            ..LiveConfig::default()
        });
        assert!(
            e.contains(
                "`live.command_hz` = 1e-30: gives no second command within control_s = 900 s"
            ),
            "{e}"
        );
        assert!(LiveConfig {
            command_hz: 0.01,
            ..LiveConfig::default()
        }
        .validate()
        .is_ok());
        let e = err(LiveConfig {
            release_s: -1e30,
            ..LiveConfig::default()
        });
        assert!(
            e.contains("`live.release_s` = -1e30: must lie within"),
            "{e}"
        );
    }

    #[test]
    fn a_group_is_tracked_per_fish_stops_only_when_every_fish_is_lost_and_reaches_goals_by_its_rule(
    ) {
        let group = |t: f64, fish: [Option<(f32, f32)>; 3]| Frame {
            t,
            robot: Some(Pose {
                x: 0.0,
                y: 0.0,
                heading: 0.0,
            }),
            fish: fish
                .iter()
                .enumerate()
                .map(|(i, f)| FishPose {
                    id: format!("fish_{}", i + 1),
                    pose: f.map(|(x, y)| Pose { x, y, heading: 0.0 }),
                })
                .collect(),
        };
        let cfg = LiveConfig {
            fish_count: 3,
            ..short()
        };
        let task = TaskParams {
            group_goal: fishprobe_sim::GroupGoal::Centroid,
            ..TaskParams::default()
        };
        let mut s = Session::new(cfg, task, Box::new(Straight), TrialKind::Virtual).unwrap();
        let mut stopped = false;
        for k in 0..300 {
            let t = 100.0 + f64::from(k) * 0.04;
            let fish = if k < 150 {
                // Fish 3 untracked throughout: no stop, one tracked fish suffices.
                [Some((30.0, 30.0)), Some((31.0, 30.0)), None]
            } else if k < 200 {
                // One fish in the first goal, the centroid far off: no goal.
                [Some((-20.0, -20.0)), Some((30.0, 30.0)), None]
            } else {
                // Both tracked fish around the goal: the centroid is inside it.
                [Some((-22.0, -20.0)), Some((-18.0, -20.0)), None]
            };
            for m in s.on_frame(&group(t, fish)) {
                if let Command { stop: true, .. } = m {
                    stopped = true;
                }
            }
            if k == 199 {
                assert_eq!(
                    s.goals_reached(),
                    0,
                    "one fish in the goal is not the centroid"
                );
            }
        }
        assert!(
            !stopped,
            "a group with one untracked fish stopped the robot"
        );
        assert_eq!(s.goals_reached(), 1);
        let f = s.trial_file("virtual guppy");
        let fish: Vec<&Entity> = f.fish().collect();
        assert_eq!(fish.len(), 3);
        assert!(fish[2].positions.iter().all(|p| p[0].is_nan()));
        assert!(fish[1].positions.iter().all(|p| p[0].is_finite()));

        // Every fish lost past the release: the robot stops.
        let mut s = Session::new(
            LiveConfig {
                fish_count: 3,
                ..short()
            },
            TaskParams::default(),
            Box::new(Straight),
            TrialKind::Real,
        )
        .unwrap();
        let mut reason = None;
        for k in 0..150 {
            let t = 100.0 + f64::from(k) * 0.04;
            for m in s.on_frame(&group(t, [None, None, None])) {
                if let Command {
                    stop: true,
                    reason: r,
                    ..
                } = m
                {
                    reason = r;
                }
            }
        }
        assert!(reason.is_some_and(|r| r.contains("fish not tracked")));
        let bad = LiveConfig {
            fish_count: 17,
            ..short()
        };
        let e = Session::new(
            bad,
            TaskParams::default(),
            Box::new(Straight),
            TrialKind::Real,
        );
        assert!(e.err().unwrap().to_string().contains("fish_count"));
    }
}
