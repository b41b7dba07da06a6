//! The BioTracker source: BioTracker's updates in, the trial host's events out (a recording
//! starts a trial, a new tracked frame is a frame, the recording's end or an unusable state
//! ends it), the robot's commands and the trials' ends back. Free of sockets: the component
//! (`component.rs`) carries the updates in and the commands to the robot sink. The trial's
//! life (pilot, provenance, file, checkpoints, keeping) is the [`TrialHost`]'s, the same as
//! for the NDJSON bridge (`live serve`).

use super::frames::{check_experiment, frame_of, EntityIds, Expected, RecordingGate, Step};
use super::schema::{Experiment, SkeletonDescriptor};
use crate::error::LiveError;
use crate::host::{
    Ended, HostConfig, PilotMaker, Reactions, SourceEvent, Started, TrialHost, TrialOutcome,
    TrialStart,
};
use crate::session::LiveConfig;
use crate::track::Command;
use fishprobe_io::TrialKind;
use fishprobe_sim::TaskParams;
use std::path::PathBuf;

/// What the observer asks its front end to do.
#[derive(Debug, Clone, PartialEq)]
pub enum Event {
    /// Send this command to the robot.
    Command(Command),
    /// Write this line to the component's log.
    Log(String),
    /// A trial began; its file will be written here.
    Started(PathBuf),
    /// A trial ended and was kept.
    Ended(TrialOutcome),
}

/// What the observer keeps of the running trial besides the host's.
struct Trial {
    skeleton: SkeletonDescriptor,
    last_t: f64,
    /// Since when (trial time, s) no robot program has been connected, if so.
    absent_since: Option<f64>,
    /// Intervals (trial time, s) without a robot program.
    absences: Vec<[f64; 2]>,
}

/// The observer's state between updates; see the module's docs.
pub struct Observer<P: PilotMaker> {
    host: TrialHost<P>,
    ids: EntityIds,
    expected: Expected,
    gate: RecordingGate,
    refusal: Option<String>,
    trial: Option<Trial>,
    robot_connected: bool,
}

impl<P: PilotMaker> std::fmt::Debug for Observer<P> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Observer")
            .field("ids", &self.ids)
            .field("in_trial", &self.trial.is_some())
            .field("refusal", &self.refusal)
            .finish()
    }
}

/// The host's answers, said as [`Event`]s; with what the observer records in a trial's file.
struct Say<'a> {
    out: &'a mut Vec<Event>,
    trial: &'a mut Option<Trial>,
    stale: u64,
    refused: Option<String>,
}

impl Reactions for Say<'_> {
    fn command(&mut self, c: Command) {
        self.out.push(Event::Command(c));
    }

    fn warn(&mut self, line: &str) {
        self.out.push(Event::Log(line.to_string()));
    }

    fn started(&mut self, s: &Started) {
        self.out.push(Event::Log(format!(
            "trial started: policy {}, file {}",
            s.policy,
            s.file.display()
        )));
        self.out.push(Event::Started(s.file.clone()));
        self.out.extend(s.warnings.iter().cloned().map(Event::Log));
    }

    fn refused(&mut self, why: &str) {
        self.refused = Some(why.to_string());
    }

    fn ended(&mut self, e: &Ended) {
        *self.trial = None;
        self.out.push(Event::Command(e.stop.clone()));
        let o = &e.outcome;
        if let Some(w) = &o.warning {
            self.out.push(Event::Log(w.clone()));
        }
        self.out.push(Event::Log(format!(
            "trial ended ({}): {} frames, {} goals reached{}",
            e.reason.as_deref().unwrap_or("the client ended it"),
            o.frames,
            o.goals_reached,
            o.file
                .as_ref()
                .map_or_else(String::new, |f| format!(", written to {}", f.display()))
        )));
        self.out.push(Event::Ended(o.clone()));
    }

    fn done_reason(&self) -> Option<String> {
        Some("the protocol's control time is over".into())
    }

    fn closing_notes(&mut self) -> Vec<(String, serde_json::Value)> {
        let mut notes = vec![("stale_updates_dropped".to_string(), self.stale.into())];
        if let Some(t) = self.trial.as_mut() {
            if let Some(a) = t.absent_since.take() {
                t.absences.push([a, t.last_t]);
            }
            notes.push((
                "robot_program_absent_s".into(),
                serde_json::json!(t.absences),
            ));
        }
        notes
    }
}

impl<P: PilotMaker> Observer<P> {
    /// An observer writing trials under `out` (`<out>/<Policy>__Real/`), following the
    /// tracker's recording when `follow_recording` is set, flown by the pilots `pilot` makes.
    /// `fallback_dir` is where a trial goes that cannot be written under `out` (see
    /// [`crate::keep`]).
    #[allow(clippy::too_many_arguments)] // each is one of the config entry's settings
    pub fn new(
        live: LiveConfig,
        task: TaskParams,
        out: PathBuf,
        ids: EntityIds,
        expected: Expected,
        follow_recording: bool,
        fallback_dir: Option<PathBuf>,
        pilot: P,
    ) -> Result<Self, LiveError> {
        ids.validate()?;
        if ids.fish.len() != live.fish_count as usize {
            return Err(LiveError::Observer(format!(
                "{} fish entity ids for a protocol of {} fish",
                ids.fish.len(),
                live.fish_count
            )));
        }
        let host = TrialHost::new(
            HostConfig {
                live,
                task,
                out,
                fish_label: "live guppy".into(),
                fallback_dir,
            },
            pilot,
        )?;
        Ok(Self {
            host,
            ids,
            expected,
            gate: RecordingGate::new(follow_recording),
            refusal: None,
            trial: None,
            robot_connected: true,
        })
    }

    /// Whether a trial is running.
    pub fn in_trial(&self) -> bool {
        self.host.in_trial()
    }

    /// Updates dropped because their frame number was not newer than the last one's.
    pub fn stale_updates(&self) -> u64 {
        self.gate.stale()
    }

    /// Why the tracker's state is refused, while it is.
    pub fn refusal(&self) -> Option<&str> {
        self.refusal.as_deref()
    }

    /// Whether a robot program is reading the commands (the robot sink's state), set before
    /// each update: the trial file records the intervals without one.
    pub fn set_robot_connected(&mut self, connected: bool) {
        self.robot_connected = connected;
    }

    /// Records `value` under `key` in the running trial's file (see
    /// [`crate::session::Session::note`]).
    pub fn note(&mut self, key: &str, value: serde_json::Value) {
        self.host.note(key, value);
    }

    /// Applies `ev` to the host; the reason when a trial could not begin.
    fn apply(&mut self, ev: SourceEvent, out: &mut Vec<Event>) -> Option<String> {
        let mut say = Say {
            out,
            trial: &mut self.trial,
            stale: self.gate.stale(),
            refused: None,
        };
        self.host.apply(ev, &mut say);
        say.refused
    }

    /// One update from the tracker core. Returns whether it was a new tracked frame (a frame
    /// number after the last one, of a state the trial accepts): the only sign of life the
    /// component counts, for the silence stop and for the robot program's watchdog ticks. A
    /// repeated, backwards or wrapped frame number, or a refused state, is none.
    pub fn on_update(&mut self, e: &Experiment, out: &mut Vec<Event>) -> bool {
        let skeleton = match check_experiment(e, &self.ids, &self.expected) {
            Ok(s) => s,
            Err(why) => {
                self.refuse(why.to_string(), out);
                return false;
            }
        };
        // The skeleton's layout says which nodes are the front and the centre: frames of
        // another layout are not frames of this trial.
        if let Some(t) = &self.trial {
            if t.skeleton != skeleton {
                let why = format!(
                    "the skeleton changed during the trial (front/centre nodes {}/{} became {}/{})",
                    t.skeleton.front_index,
                    t.skeleton.center_index,
                    skeleton.front_index,
                    skeleton.center_index
                );
                self.finish(&why, out);
                out.push(Event::Log(format!(
                    "trial ended: {why}; the next recording starts a new one"
                )));
                return false;
            }
        }
        if let Some(was) = self.refusal.take() {
            out.push(Event::Log(format!(
                "the tracker's state is accepted now (it was refused: {was})"
            )));
        }
        match self.gate.step(e) {
            Step::Stale => return false,
            Step::Idle => {}
            Step::Start { stem, origin, t } => {
                let start = self.trial_start(e, stem, origin);
                if let Some(why) = self.apply(SourceEvent::Begin(start), out) {
                    self.gate.close();
                    self.refuse(why, out);
                    return false;
                }
                self.trial = Some(Trial {
                    skeleton,
                    last_t: 0.0,
                    absent_since: None,
                    absences: Vec::new(),
                });
                self.frame(e, t, out);
            }
            Step::Frame { t } => self.frame(e, t, out),
            Step::End => self.finish("the recording finished", out),
        }
        true
    }

    /// How a trial of the recording `stem` (starting at tracking time `origin`) begins.
    fn trial_start(&self, e: &Experiment, stem: Option<String>, origin: f64) -> TrialStart {
        let mut notes = vec![
            (
                "tracker".to_string(),
                "BioTracker v4 (observer component)".into(),
            ),
            ("tracker_target_fps".into(), f64::from(e.target_fps).into()),
            (
                "entity_ids".into(),
                serde_json::json!({ "robot": self.ids.robot, "fish": self.ids.fish }),
            ),
        ];
        if e.target_fps != self.expected.fps {
            notes.push(("accepted_other_fps".into(), true.into()));
        }
        if let Some(c) = &e.recording_config {
            notes.push(("recording_base_path".into(), c.base_path.clone().into()));
        }
        TrialStart {
            kind: TrialKind::Real,
            stem,
            origin: Some(origin),
            notes,
            checkpoints: true,
        }
    }

    /// No update for `silence_s` of wall-clock time: the session's silence stop.
    pub fn on_silence(&mut self, silence_s: f64, out: &mut Vec<Event>) {
        if self.in_trial() {
            self.apply(SourceEvent::Silence(silence_s), out);
        }
    }

    /// Ends the running trial now (the tracker core is gone, the component stops): the robot
    /// is stopped and the trial kept, with `reason` in its file.
    pub fn finish(&mut self, reason: &str, out: &mut Vec<Event>) {
        self.gate.close();
        if self.in_trial() {
            self.apply(SourceEvent::End(Some(reason.to_string())), out);
        }
        self.trial = None;
    }

    /// Trials that could not be written anywhere (held in memory).
    pub fn unsaved(&mut self) -> Vec<PathBuf> {
        self.host.unsaved()
    }

    fn refuse(&mut self, why: String, out: &mut Vec<Event>) {
        if self.in_trial() {
            self.finish(&format!("the tracker's state became unusable: {why}"), out);
        }
        if self.refusal.as_deref() != Some(why.as_str()) {
            out.push(Event::Log(format!(
                "refused, the robot stays stopped: {why}"
            )));
            out.push(Event::Command(Command::stop_outside_trial(0.0, &why, 0)));
            self.refusal = Some(why);
        }
    }

    fn frame(&mut self, e: &Experiment, t: f64, out: &mut Vec<Event>) {
        let Some(trial) = &mut self.trial else {
            return;
        };
        let frame = frame_of(e, &trial.skeleton, &self.ids, t);
        trial.last_t = t;
        match (self.robot_connected, trial.absent_since) {
            (false, None) => trial.absent_since = Some(t),
            (true, Some(a)) => {
                trial.absences.push([a, t]);
                trial.absent_since = None;
            }
            _ => {}
        }
        self.apply(SourceEvent::Frame(frame), out);
        if self.trial.is_none() {
            // The host ended it (the protocol's time is over): wait for the next recording.
            self.gate.close();
        }
    }
}
