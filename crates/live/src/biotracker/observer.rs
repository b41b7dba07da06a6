//! The observer's trial logic, free of sockets: BioTracker's updates in, robot commands and
//! finished trials out. It feeds the same [`Session`] as the bridge (`live serve`): the same
//! protocol phases, goal logic, safety stops and trial file.

use super::frames::{check_experiment, frame_of, EntityIds, Expected, RecordingGate, Step};
use super::schema::{Experiment, SkeletonDescriptor};
use crate::error::LiveError;
use crate::keep::Keeper;
use crate::protocol::ServerMsg;
use crate::server::{check_provenance, next_free, TrialOutcome};
use crate::session::{LiveConfig, Session};
use fishprobe_io::{Arm, StudyLayout};
use fishprobe_sim::{Controller, TaskParams};
use std::path::{Path, PathBuf};

/// Makes the pilot (policy) of a trial.
pub type PilotMaker<'a> = dyn FnMut() -> Result<Box<dyn Controller>, LiveError> + 'a;

/// What the observer asks its front end to do.
#[derive(Debug, Clone, PartialEq)]
pub enum Event {
    /// Send this command to the robot.
    Command(ServerMsg),
    /// Write this line to the component's log.
    Log(String),
    /// A trial began; its file will be written here.
    Started(PathBuf),
    /// A trial ended and was kept.
    Ended(TrialOutcome),
}

struct Trial {
    session: Session,
    skeleton: SkeletonDescriptor,
    file: PathBuf,
    last_t: f64,
    /// Since when (trial time, s) no robot program has been connected, if so.
    absent_since: Option<f64>,
    /// Intervals (trial time, s) without a robot program.
    absences: Vec<[f64; 2]>,
}

/// The observer's state between updates; see the module's docs.
pub struct Observer {
    live: LiveConfig,
    task: TaskParams,
    out: PathBuf,
    ids: EntityIds,
    expected: Expected,
    gate: RecordingGate,
    refusal: Option<String>,
    trial: Option<Trial>,
    keeper: Keeper,
    n: usize,
    robot_connected: bool,
}

impl std::fmt::Debug for Observer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Observer")
            .field("ids", &self.ids)
            .field("in_trial", &self.trial.is_some())
            .field("refusal", &self.refusal)
            .finish()
    }
}

impl Observer {
    /// An observer writing trials under `out` (`<out>/<Policy>__Real/`), following the
    /// tracker's recording when `follow_recording` is set. `fallback_dir` is where a trial
    /// goes that cannot be written under `out` (see [`crate::keep`]).
    pub fn new(
        live: LiveConfig,
        task: TaskParams,
        out: PathBuf,
        ids: EntityIds,
        expected: Expected,
        follow_recording: bool,
        fallback_dir: Option<PathBuf>,
    ) -> Result<Self, LiveError> {
        live.validate()?;
        ids.validate()?;
        if ids.fish.len() != live.fish_count as usize {
            return Err(LiveError::Observer(format!(
                "{} fish entity ids for a protocol of {} fish",
                ids.fish.len(),
                live.fish_count
            )));
        }
        Ok(Self {
            live,
            task,
            out,
            ids,
            expected,
            gate: RecordingGate::new(follow_recording),
            refusal: None,
            trial: None,
            keeper: Keeper::new(fallback_dir),
            n: 0,
            robot_connected: true,
        })
    }

    /// Whether a trial is running.
    pub fn in_trial(&self) -> bool {
        self.trial.is_some()
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

    /// Records `value` under `key` in the running trial's file (see [`Session::note`]).
    pub fn note(&mut self, key: &str, value: serde_json::Value) {
        if let Some(t) = &mut self.trial {
            t.session.note(key, value);
        }
    }

    /// One update from the tracker core. Returns whether it was a new tracked frame (a frame
    /// number after the last one, of a state the trial accepts): the only sign of life the
    /// component counts, for the silence stop and for the robot program's watchdog ticks. A
    /// repeated, backwards or wrapped frame number, or a refused state, is none.
    pub fn on_update(
        &mut self,
        e: &Experiment,
        pilot: &mut PilotMaker<'_>,
        out: &mut Vec<Event>,
    ) -> bool {
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
                if let Some(why) = self.start(e, skeleton, stem.as_deref(), origin, pilot, out) {
                    self.gate.close();
                    self.refuse(why, out);
                    return false;
                }
                self.frame(e, t, out);
            }
            Step::Frame { t } => self.frame(e, t, out),
            Step::End => self.finish("the recording finished", out),
        }
        true
    }

    /// No update for `silence_s` of wall-clock time: the session's silence stop.
    pub fn on_silence(&mut self, silence_s: f64, out: &mut Vec<Event>) {
        if let Some(t) = &mut self.trial {
            out.extend(
                t.session
                    .on_silence(silence_s)
                    .into_iter()
                    .map(Event::Command),
            );
        }
    }

    /// Ends the running trial now (the tracker core is gone, the component stops): the robot
    /// is stopped and the trial kept, with `reason` in its file.
    pub fn finish(&mut self, reason: &str, out: &mut Vec<Event>) {
        self.gate.close();
        let Some(mut trial) = self.trial.take() else {
            return;
        };
        let session = &mut trial.session;
        session.note("ended_because", reason.into());
        session.note("stale_updates_dropped", self.gate.stale().into());
        if let Some(a) = trial.absent_since.take() {
            trial.absences.push([a, trial.last_t]);
        }
        session.note("robot_program_absent_s", serde_json::json!(trial.absences));
        out.push(Event::Command(ServerMsg::stop_outside_trial(
            trial.last_t,
            reason,
            session.goals_reached(),
        )));
        let kept = self
            .keeper
            .keep(&trial.file, session.trial_file("live guppy"));
        self.keeper.retry();
        if let Some(w) = kept.warning() {
            out.push(Event::Log(w));
        }
        out.push(Event::Log(format!(
            "trial ended ({reason}): {} frames, {} goals reached{}",
            session.frames(),
            session.goals_reached(),
            kept.written()
                .map_or_else(String::new, |f| format!(", written to {}", f.display()))
        )));
        out.push(Event::Ended(TrialOutcome::of(&kept, session)));
    }

    /// Trials that could not be written anywhere (held in memory).
    pub fn unsaved(&mut self) -> Vec<PathBuf> {
        self.keeper.retry();
        self.keeper
            .unsaved()
            .into_iter()
            .map(Path::to_path_buf)
            .collect()
    }

    fn refuse(&mut self, why: String, out: &mut Vec<Event>) {
        if self.trial.is_some() {
            self.finish(&format!("the tracker's state became unusable: {why}"), out);
        }
        if self.refusal.as_deref() != Some(why.as_str()) {
            out.push(Event::Log(format!(
                "refused, the robot stays stopped: {why}"
            )));
            out.push(Event::Command(ServerMsg::stop_outside_trial(0.0, &why, 0)));
            self.refusal = Some(why);
        }
    }

    /// Starts a trial; returns why not.
    fn start(
        &mut self,
        e: &Experiment,
        skeleton: SkeletonDescriptor,
        stem: Option<&str>,
        origin: f64,
        pilot: &mut PilotMaker<'_>,
        out: &mut Vec<Event>,
    ) -> Option<String> {
        let pilot = match pilot() {
            Ok(p) => p,
            Err(err) => return Some(format!("the policy cannot be made: {err}")),
        };
        if let Err(err) = check_provenance(&self.out, pilot.as_ref()) {
            return Some(err.to_string());
        }
        let mut session = match Session::new(self.live.clone(), self.task.clone(), pilot, "lab") {
            Ok(s) => s,
            Err(err) => return Some(err.to_string()),
        };
        session.set_origin(origin);
        session.note("tracker", "BioTracker v4 (observer component)".into());
        session.note("tracker_target_fps", f64::from(e.target_fps).into());
        if e.target_fps != self.expected.fps {
            session.note("accepted_other_fps", true.into());
        }
        session.note(
            "entity_ids",
            serde_json::json!({ "robot": self.ids.robot, "fish": self.ids.fish }),
        );
        if let Some(c) = &e.recording_config {
            session.note("recording_base_path", c.base_path.clone().into());
        }
        let dir = self.out.join(StudyLayout::arm_dir_name(
            &StudyLayout::safe_name(&session.policy()),
            &Arm::Real,
        ));
        let file = match stem {
            Some(stem) => free_named(&dir, stem),
            None => next_free(&dir, &mut self.n),
        };
        out.push(Event::Log(format!(
            "trial started: policy {}, file {}",
            session.policy(),
            file.display()
        )));
        out.push(Event::Started(file.clone()));
        // The descriptors the trial's file needs are held from now on.
        if !self.keeper.reserve() {
            out.push(Event::Log(
                "no file descriptors spare as the trial starts; its file may fall back".into(),
            ));
        }
        self.trial = Some(Trial {
            session,
            skeleton,
            file,
            last_t: 0.0,
            absent_since: None,
            absences: Vec::new(),
        });
        None
    }

    fn frame(&mut self, e: &Experiment, t: f64, out: &mut Vec<Event>) {
        let Some(trial) = &mut self.trial else {
            return;
        };
        let msg = frame_of(e, &trial.skeleton, &self.ids, t);
        trial.last_t = t;
        match (self.robot_connected, trial.absent_since) {
            (false, None) => trial.absent_since = Some(t),
            (true, Some(a)) => {
                trial.absences.push([a, t]);
                trial.absent_since = None;
            }
            _ => {}
        }
        out.extend(
            trial
                .session
                .on_message(msg)
                .into_iter()
                .map(Event::Command),
        );
        if trial.session.checkpoint_due() {
            let f = trial.session.checkpoint_file("live guppy");
            if let Some(e) = self.keeper.checkpoint(&trial.file, f) {
                out.push(Event::Log(format!("checkpoint not written: {e}")));
            }
        }
        if trial.session.is_done() {
            self.finish("the protocol's control time is over", out);
        }
    }
}

/// `<dir>/<stem>.hdf5`, or `<stem>_2.hdf5`, `_3`, ... when taken.
fn free_named(dir: &Path, stem: &str) -> PathBuf {
    let first = dir.join(format!("{stem}.hdf5"));
    if !first.exists() {
        return first;
    }
    (2u64..)
        .map(|k| dir.join(format!("{stem}_{k}.hdf5")))
        .find(|p| !p.exists())
        .unwrap_or(first)
}
