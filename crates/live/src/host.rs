//! The trial host: one trial's life around a [`Session`], the same for every tracker source.
//! It makes the pilot, checks that the output directory holds no other policy's trials under
//! its name, names the trial's file, secures what writing it needs, checkpoints it, ends it
//! with a reason and keeps it (see [`crate::keep`]), and says what came of it.
//!
//! A tracker source (the NDJSON bridge's connection, BioTracker's observer component) is a
//! [`TrackerSource`]: it turns its own messages into [`SourceEvent`]s (a trial begins, a
//! frame, an unusable message, silence, the trial ends) and carries the host's answers back
//! (the robot's commands, the trial's start and end). [`drive`] runs one source against the
//! host until the source is done, and ends the running trial politely when the process is
//! asked to stop ([`crate::shutdown`]). A new tracker source is one such type.

use crate::error::LiveError;
use crate::keep::{Keeper, Kept};
use crate::session::{LiveConfig, Session};
use crate::track::{Command, Frame};
use fishprobe_io::{Arm, StudyLayout, TrialKind};
use fishprobe_sim::{Controller, TaskParams};
use std::path::{Path, PathBuf};

/// Makes the pilot (policy) of a trial: any `FnMut() -> Result<Box<dyn Controller>, LiveError>`.
pub trait PilotMaker: FnMut() -> Result<Box<dyn Controller>, LiveError> {}
impl<F: FnMut() -> Result<Box<dyn Controller>, LiveError>> PilotMaker for F {}

/// Where and how the host keeps trials.
#[derive(Debug, Clone)]
pub struct HostConfig {
    /// Trial protocol and safety settings.
    pub live: LiveConfig,
    /// Goals and goal radius (evaluation goals).
    pub task: TaskParams,
    /// Where trial files go: `<out>/<Policy>__Real/` or `<out>/<Policy>__VirtualLab/`.
    pub out: PathBuf,
    /// The fish's label in the files of real trials ("live guppy"); virtual-lab trials say
    /// "virtual guppy".
    pub fish_label: String,
    /// Where a trial goes that cannot be written under `out` (None: the system's temporary
    /// directory, `fishprobe-unsaved/`).
    pub fallback_dir: Option<PathBuf>,
}

/// How a trial begins.
#[derive(Debug, Clone, PartialEq)]
pub struct TrialStart {
    /// A trial with live fish, or the virtual lab's.
    pub kind: TrialKind,
    /// The file's name without `.hdf5` (BioTracker's recording's name); none: `trial_NNN`.
    pub stem: Option<String>,
    /// The tracking time at which the trial's time begins; none: its first frame's.
    pub origin: Option<f64>,
    /// What the source records about itself in the trial's file (see [`Session::note`]).
    pub notes: Vec<(String, serde_json::Value)>,
    /// Write the running trial now and then (a live trial; the virtual lab in lockstep is
    /// reproducible and run again instead).
    pub checkpoints: bool,
}

/// A trial that began.
#[derive(Debug, Clone, PartialEq)]
pub struct Started {
    /// The pilot's name.
    pub policy: String,
    /// The SHA-256 of its weights (none for a scripted pilot).
    pub fingerprint: Option<String>,
    /// Where its file will be written.
    pub file: PathBuf,
    /// What went wrong preparing it (it runs anyway).
    pub warnings: Vec<String>,
}

/// What one trial produced.
#[derive(Debug, Clone, PartialEq)]
pub struct TrialOutcome {
    /// The trial file (None when it is held in memory because nothing could be written).
    pub file: Option<PathBuf>,
    /// Goals reached.
    pub goals_reached: u32,
    /// Whether the trial ran to its end (else it ended early).
    pub complete: bool,
    /// Frames recorded.
    pub frames: usize,
    /// What went wrong writing the trial (it went to the fallback, or stays in memory).
    pub warning: Option<String>,
}

impl TrialOutcome {
    fn of(kept: &Kept, session: &Session) -> Self {
        Self {
            file: kept.written().map(Path::to_path_buf),
            goals_reached: session.goals_reached(),
            complete: session.is_done(),
            frames: session.frames(),
            warning: kept.warning(),
        }
    }
}

/// A trial that ended.
#[derive(Debug, Clone, PartialEq)]
pub struct Ended {
    /// What it produced.
    pub outcome: TrialOutcome,
    /// Why it ended early, if it did (also in its file, `ended_because`).
    pub reason: Option<String>,
    /// The stop for the robot: it holds still from now on, and the reason says why.
    pub stop: Command,
    /// Where the file should be (also when it could not be written there).
    pub planned: PathBuf,
}

/// What a tracker source tells the host.
#[derive(Debug, Clone, PartialEq)]
pub enum SourceEvent {
    /// A trial begins (a client's hello, the tracker's recording starting).
    Begin(TrialStart),
    /// One tracked frame of the running trial.
    Frame(Frame),
    /// A message that could not be used: the robot stops, and the reason says why.
    Malformed(String),
    /// No new frame for this long (s of wall-clock time).
    Silence(f64),
    /// The trial ends (the client ended it or left, the recording stopped); with a reason
    /// when it ends before its time for a reason worth recording.
    End(Option<String>),
}

/// How a tracker source carries the host's answers back.
pub trait Reactions {
    /// A command for the robot.
    fn command(&mut self, c: Command);
    /// Something went wrong that the operator should hear of (the trial goes on).
    fn warn(&mut self, _line: &str) {}
    /// The trial began.
    fn started(&mut self, _s: &Started) {}
    /// It could not begin; why.
    fn refused(&mut self, _why: &str) {}
    /// It ended and was kept.
    fn ended(&mut self, _e: &Ended) {}
    /// Everything about the frame at `t` has been said (`accepted`: the session took it as a
    /// new frame; `done`: the trial is over).
    fn after_frame(&mut self, _t: f64, _accepted: bool, _done: bool) {}
    /// Why a trial that ran its protocol's full time ended, if the source records it.
    fn done_reason(&self) -> Option<String> {
        None
    }
    /// What the source records in the trial's file just before it ends.
    fn closing_notes(&mut self) -> Vec<(String, serde_json::Value)> {
        Vec::new()
    }
}

/// A source of tracking: see the module's docs.
pub trait TrackerSource: Reactions {
    /// The next event, after waiting no longer than the source's poll period; `None` when the
    /// source is done (the connection closed, the component stops).
    fn next_event(&mut self) -> Option<SourceEvent>;
}

struct Running {
    session: Session,
    file: PathBuf,
    label: String,
    checkpoints: bool,
}

/// The host; see the module's docs. One trial at a time.
pub struct TrialHost<P: PilotMaker> {
    cfg: HostConfig,
    pilot: P,
    keeper: Keeper,
    /// The next `trial_NNN` number to try.
    n: usize,
    /// Pilots whose directories were checked (name, weights).
    checked: Vec<(String, String)>,
    running: Option<Running>,
}

impl<P: PilotMaker> std::fmt::Debug for TrialHost<P> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("TrialHost")
            .field("out", &self.cfg.out)
            .field("in_trial", &self.running.is_some())
            .finish()
    }
}

impl<P: PilotMaker> TrialHost<P> {
    /// A host keeping trials as `cfg` says, flown by the pilots `pilot` makes.
    pub fn new(cfg: HostConfig, pilot: P) -> Result<Self, LiveError> {
        cfg.live.validate()?;
        let keeper = Keeper::new(cfg.fallback_dir.clone());
        Ok(Self {
            cfg,
            pilot,
            keeper,
            n: 0,
            checked: Vec::new(),
            running: None,
        })
    }

    /// The protocol.
    pub fn live(&self) -> &LiveConfig {
        &self.cfg.live
    }

    /// Makes a pilot and checks that `out` holds no other policy's trials under its name.
    pub fn check_pilot(&mut self) -> Result<Box<dyn Controller>, LiveError> {
        let pilot = (self.pilot)()?;
        if let Some(sha) = pilot.fingerprint() {
            let key = (pilot.name(), sha);
            if !self.checked.contains(&key) {
                check_provenance(&self.cfg.out, pilot.as_ref())?;
                self.checked.push(key);
            }
        }
        Ok(pilot)
    }

    /// Whether a trial is running.
    pub fn in_trial(&self) -> bool {
        self.running.is_some()
    }

    /// The running trial's session.
    pub fn session(&self) -> Option<&Session> {
        self.running.as_ref().map(|r| &r.session)
    }

    /// Whether the running trial has run its protocol's full time.
    pub fn is_done(&self) -> bool {
        self.running.as_ref().is_some_and(|r| r.session.is_done())
    }

    /// Begins a trial (a running one must have ended); why not, if it cannot.
    fn begin(&mut self, start: TrialStart) -> Result<Started, String> {
        if self.running.is_some() {
            return Err("a trial is running".into());
        }
        let pilot = self.check_pilot().map_err(|e| match e {
            LiveError::Mixed(why) => why,
            other => format!("the policy cannot be made: {other}"),
        })?;
        let mut session = Session::new(
            self.cfg.live.clone(),
            self.cfg.task.clone(),
            pilot,
            start.kind,
        )
        .map_err(|e| e.to_string())?;
        if let Some(t0) = start.origin {
            session.set_origin(t0);
        }
        for (k, v) in start.notes {
            session.note(&k, v);
        }
        let arm = if start.kind == TrialKind::Virtual {
            Arm::VirtualLab
        } else {
            Arm::Real
        };
        let dir = self.cfg.out.join(StudyLayout::arm_dir_name(
            &StudyLayout::safe_name(&session.policy()),
            &arm,
        ));
        let file = match start.stem.as_deref() {
            Some(stem) => free_named(&dir, stem),
            None => next_free(&dir, &mut self.n),
        };
        let mut warnings = Vec::new();
        // The descriptors the trial's file needs are held from now on, so connections
        // arriving during the trial cannot take them.
        if !self.keeper.reserve() {
            session.note(
                "file_descriptors",
                "none spare when the trial started; the file may fall back".into(),
            );
            warnings.push(
                "no file descriptors spare as the trial starts; its file may fall back".into(),
            );
        }
        let label = if start.kind == TrialKind::Virtual {
            "virtual guppy".to_string()
        } else {
            self.cfg.fish_label.clone()
        };
        let started = Started {
            policy: session.policy(),
            fingerprint: session.fingerprint(),
            file: file.clone(),
            warnings,
        };
        self.running = Some(Running {
            session,
            file,
            label,
            checkpoints: start.checkpoints,
        });
        Ok(started)
    }

    /// Records `value` under `key` in the running trial's file.
    pub fn note(&mut self, key: &str, value: serde_json::Value) {
        if let Some(r) = &mut self.running {
            r.session.note(key, value);
        }
    }

    /// A frame of the running trial; the robot's commands, and a checkpoint when one is due
    /// (a failed checkpoint's reason comes back as the second value).
    pub fn frame(&mut self, f: &Frame) -> (Vec<Command>, Option<String>) {
        let Some(r) = &mut self.running else {
            return (Vec::new(), None);
        };
        let out = r.session.on_frame(f);
        let mut failed = None;
        if r.checkpoints && r.session.checkpoint_due() {
            failed = self
                .keeper
                .checkpoint(&r.file, r.session.checkpoint_file(&r.label));
        }
        (out, failed)
    }

    /// A message that could not be used.
    pub fn malformed(&mut self, why: &str) -> Vec<Command> {
        self.running
            .as_mut()
            .map_or_else(Vec::new, |r| r.session.on_malformed(why))
    }

    /// No frame for `silence_s` of wall-clock time.
    pub fn silence(&mut self, silence_s: f64) -> Vec<Command> {
        self.running
            .as_mut()
            .map_or_else(Vec::new, |r| r.session.on_silence(silence_s))
    }

    /// Ends the running trial (with `reason` when it ends before its time for a reason worth
    /// recording) and keeps its file.
    pub fn end(&mut self, reason: Option<&str>) -> Option<Ended> {
        let mut r = self.running.take()?;
        let stop = match reason {
            Some(why) => r.session.end_early(why),
            None => Command::stop_outside_trial(
                r.session.last_time(),
                "the trial is over",
                r.session.goals_reached(),
            ),
        };
        let kept = self.keeper.keep(&r.file, r.session.trial_file(&r.label));
        // Trials held in memory since an earlier failure get another chance.
        self.keeper.retry();
        Some(Ended {
            outcome: TrialOutcome::of(&kept, &r.session),
            reason: reason.map(str::to_string),
            stop,
            planned: r.file,
        })
    }

    /// Trials that could not be written anywhere (held in memory), after one more try.
    pub fn unsaved(&mut self) -> Vec<PathBuf> {
        self.keeper.retry();
        self.keeper
            .unsaved()
            .into_iter()
            .map(Path::to_path_buf)
            .collect()
    }

    /// Applies one event of a source, answering through `r`.
    pub fn apply(&mut self, ev: SourceEvent, r: &mut dyn Reactions) {
        match ev {
            SourceEvent::Begin(start) => match self.begin(start) {
                Ok(s) => r.started(&s),
                Err(why) => r.refused(&why),
            },
            SourceEvent::Frame(f) => {
                let t = f.t;
                let before = self.session().map_or(0, Session::frames_accepted);
                let (commands, failed) = self.frame(&f);
                let accepted = self.session().map_or(0, Session::frames_accepted) > before;
                for c in commands {
                    r.command(c);
                }
                if let Some(why) = failed {
                    r.warn(&format!("checkpoint not written: {why}"));
                }
                let done = self.is_done();
                r.after_frame(t, accepted, done);
                if done {
                    let why = r.done_reason();
                    self.finish(why.as_deref(), r);
                }
            }
            SourceEvent::Malformed(why) => {
                for c in self.malformed(&why) {
                    r.command(c);
                }
            }
            SourceEvent::Silence(s) => {
                for c in self.silence(s) {
                    r.command(c);
                }
            }
            SourceEvent::End(reason) => self.finish(reason.as_deref(), r),
        }
    }

    /// Ends the running trial with the source's closing notes, and tells the source.
    pub fn finish(&mut self, reason: Option<&str>, r: &mut dyn Reactions) {
        if !self.in_trial() {
            return;
        }
        for (k, v) in r.closing_notes() {
            self.note(&k, v);
        }
        if let Some(e) = self.end(reason) {
            r.ended(&e);
        }
    }
}

/// Runs `source` against `host` until the source is done. When the process is asked to stop
/// (SIGTERM, SIGINT, SIGHUP), the running trial ends with the reason and the loop returns.
/// Returns whether it stopped for that.
pub fn drive<P: PilotMaker>(host: &mut TrialHost<P>, source: &mut dyn TrackerSource) -> bool {
    loop {
        if let Some(why) = crate::shutdown::requested() {
            host.finish(Some(&why), source);
            return true;
        }
        match source.next_event() {
            Some(ev) => host.apply(ev, source),
            None => {
                host.finish(None, source);
                return false;
            }
        }
    }
}

/// Refuses to add the pilot's trials to directories that hold another policy's under its
/// name (trials that record no fingerprint, from scripted pilots or older files, pass).
pub fn check_provenance(out: &Path, pilot: &dyn Controller) -> Result<(), LiveError> {
    let Some(sha) = pilot.fingerprint() else {
        return Ok(());
    };
    let name = StudyLayout::safe_name(&pilot.name());
    for arm in [Arm::Real, Arm::VirtualLab] {
        let dir = out.join(StudyLayout::arm_dir_name(&name, &arm));
        let p = fishprobe_io::Provenance::of_dir(&dir, &sha);
        if let Some(why) = p.describe_other(&dir, &sha) {
            return Err(LiveError::Mixed(why));
        }
        // The host writes whole files only: one it cannot read was put there by hand.
        if let Some((f, e)) = p.unreadable.first() {
            return Err(LiveError::Mixed(format!(
                "{} cannot be read ({e}), so which policy drove it cannot be told",
                f.display()
            )));
        }
    }
    Ok(())
}

/// `<dir>/trial_NNN.hdf5`, the first free one from `n` on.
fn next_free(dir: &Path, n: &mut usize) -> PathBuf {
    loop {
        let p = dir.join(format!("trial_{:03}.hdf5", *n));
        *n += 1;
        if !p.exists() {
            return p;
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
