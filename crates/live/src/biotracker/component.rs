//! The observer component as a whole: the gRPC calls hand updates to one session thread over a
//! bounded queue, the session thread runs the [`Observer`] and feeds the robot sink, and a
//! heartbeat to the core ends everything safely when the core is gone.
//!
//! Nothing here writes to stdout or stderr: they are pipes into the core's log and fail once the
//! core dies. Everything the component has to say goes to its log file.

use super::grpc::{self, Client, ObserverCalls};
use super::observer::{Event, Observer};
use super::schema::{ComponentConfig, Experiment};
use super::{Expected, ObserverSettings};
use crate::session::LiveConfig;
use crate::sink::RobotSink;
use crate::track::Command;
use crate::LiveError;
use fishprobe_sim::{Controller, TaskParams};
use std::collections::VecDeque;
use std::io::Write;
use std::net::{SocketAddr, TcpListener};
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Condvar, Mutex, MutexGuard, PoisonError};
use std::time::{Duration, Instant};
use tonic::Status;

fishprobe_sim::documented_params! {
    /// How the observer component defends itself and watches the core (not the trial
    /// protocol).
    pub struct ComponentGuard {
        /// Updates waiting for the session thread at most (choice: 8, a third of a second at
        /// 25 Hz); beyond, the oldest is dropped and counted, so a flood never grows memory
        /// and the session always works on the newest frames.
        pub queue: usize = 8; "updates",
        /// Largest request accepted (choice: 1 MiB; a frame of 16 fish is under 10 kB).
        pub max_message_bytes: usize = 1_048_576; "bytes",
        /// Heartbeat period to the core (BioTracker's components beat once a second).
        pub heartbeat_s: f64 = 1.0; "s",
        /// Failed heartbeats in a row that mean the core is gone (choice: 2; with the
        /// period and the call timeout below the robot stops within 3 s of the core's end).
        pub heartbeat_failures: u32 = 2; "1",
        /// Longest a heartbeat may take before it counts as failed.
        pub heartbeat_timeout_s: f64 = 0.5; "s",
        /// Longest loading a configuration's policy and settings may take before the
        /// configuration is refused (choice: 30 s; a path naming a FIFO or a hung disk would
        /// otherwise never answer). Loading runs beside the tracking updates, which are
        /// answered meanwhile.
        pub config_load_s: f64 = 30.0; "s",
        /// Connections the gRPC port holds at once (choice: 16; the core needs one, a
        /// reconnecting core a second). One more closes the connection silent longest, never
        /// the tracker's, which sends every frame; so idle peers cannot take the file
        /// descriptors a trial file needs.
        pub max_connections: usize = 16; "connections",
        /// A new gRPC connection must send its first bytes within this long (choice: 2 s; a
        /// gRPC client sends its preface at once).
        pub connection_first_bytes_s: f64 = 2.0; "s",
        /// A gRPC connection that sends nothing for this long is closed (choice: 60 s, three
        /// keepalive pings unanswered).
        pub connection_idle_s: f64 = 60.0; "s",
        /// The observer pings each gRPC connection this often (choice: 20 s); a live peer's
        /// transport answers, so only a dead or hostile one goes idle.
        pub keepalive_s: f64 = 20.0; "s",
    }
}

/// Longest reason the component puts into a gRPC status or a log line (characters; choice:
/// 2,000): a 900 kB policy name must not become a 1.8 MB log line or an error the core's
/// transport refuses.
pub const MAX_REASON_CHARS: usize = 2000;

/// `text` cut to at most `max` characters, saying how much was left out.
pub fn clip(text: &str, max: usize) -> String {
    match text.char_indices().nth(max) {
        None => text.to_string(),
        Some((at, _)) => format!("{}… ({} more bytes)", &text[..at], text.len() - at),
    }
}

impl ComponentGuard {
    /// Checks the ranges.
    pub fn validate(&self) -> Result<(), fishprobe_sim::ConfigError> {
        use fishprobe_sim::ConfigError;
        if !(1..=4096).contains(&self.queue) {
            return Err(ConfigError::new(
                "observer",
                "queue",
                self.queue,
                "must lie in [1, 4096]",
            ));
        }
        if !(4096..=64 << 20).contains(&self.max_message_bytes) {
            return Err(ConfigError::new(
                "observer",
                "max_message_bytes",
                self.max_message_bytes,
                "must lie in [4096, 64 MiB]",
            ));
        }
        for (f, v, hi) in [
            ("heartbeat_s", self.heartbeat_s, 60.0),
            ("heartbeat_timeout_s", self.heartbeat_timeout_s, 60.0),
            ("config_load_s", self.config_load_s, 3600.0),
            (
                "connection_first_bytes_s",
                self.connection_first_bytes_s,
                600.0,
            ),
            ("connection_idle_s", self.connection_idle_s, 86_400.0),
            ("keepalive_s", self.keepalive_s, 3600.0),
        ] {
            if !(v.is_finite() && v > 0.0 && v <= hi) {
                return Err(ConfigError::new(
                    "observer",
                    f,
                    v,
                    &format!("must lie in (0, {hi}]"),
                ));
            }
        }
        if !(1..=1024).contains(&self.max_connections) {
            return Err(ConfigError::new(
                "observer",
                "max_connections",
                self.max_connections,
                "must lie in [1, 1024]",
            ));
        }
        if !(1..=100).contains(&self.heartbeat_failures) {
            return Err(ConfigError::new(
                "observer",
                "heartbeat_failures",
                self.heartbeat_failures,
                "must lie in [1, 100]",
            ));
        }
        Ok(())
    }
}

impl ComponentGuard {
    /// The gRPC port's connection limits.
    pub fn connection_limits(&self) -> grpc::ConnectionLimits {
        grpc::ConnectionLimits {
            max_connections: self.max_connections,
            first_bytes_s: self.connection_first_bytes_s,
            idle_s: self.connection_idle_s,
            keepalive_s: self.keepalive_s,
        }
    }
}

/// What a config entry's settings load into (the binary loads policies and settings files).
pub struct Prepared {
    /// The trial protocol.
    pub live: LiveConfig,
    /// Goals.
    pub task: TaskParams,
    /// The tracking rate the policy was trained at (Hz).
    pub trained_fps: f32,
    /// Makes the pilot of each trial.
    pub pilot: Pilots,
}

/// Loads what a config entry names: the policy (checked to fit the fish count) and the
/// protocol's settings. An error says what is wrong, for the core's user.
pub type Loader = dyn Fn(&ObserverSettings) -> Result<Prepared, LiveError> + Send + Sync;

/// Makes the pilot of each trial of a configuration.
type Pilots = Box<dyn FnMut() -> Result<Box<dyn Controller>, LiveError> + Send>;

struct Active {
    settings: ObserverSettings,
    /// The output directory's one-writer lock (as `live serve` takes it), held while
    /// configured: two commands writing trials into one directory would mix them.
    lock: fishprobe_io::DirLock,
    observer: Observer<Pilots>,
    sink: RobotSink,
}

#[derive(Default)]
struct Queue {
    updates: VecDeque<Experiment>,
    dropped: u64,
}

/// A line-per-event log file; writing failures are ignored (there is nowhere else to say so).
struct Log(Option<std::fs::File>);

impl Log {
    fn line(&mut self, what: &str) {
        if let Some(f) = &mut self.0 {
            let _ = writeln!(
                f,
                "{} {}",
                crate::utc_stamp(std::time::SystemTime::now()),
                clip(what, 4 * MAX_REASON_CHARS)
            );
        }
    }
}

/// What the gRPC handlers, the session thread and the heartbeat share.
struct Host {
    loader: Arc<Loader>,
    /// Set once the first `set_config` was answered: BioTracker's core drops a component whose
    /// first configuration fails and refuses every later edit of it, so the first is always
    /// answered with success (a refused one leaves the component unconfigured, the robot
    /// stopped, the problems in the log and on stderr) and only later ones are refused.
    answered_first: AtomicBool,
    guard: ComponentGuard,
    fallback_dir: Option<PathBuf>,
    queue: Mutex<Queue>,
    ready: Condvar,
    active: Mutex<Option<Active>>,
    log: Mutex<Log>,
    core: Mutex<SocketAddr>,
    /// Set when the component must end (the reason).
    ending: Mutex<Option<String>>,
    stop: AtomicBool,
}

fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(PoisonError::into_inner)
}

impl Host {
    fn log(&self, what: &str) {
        lock(&self.log).line(what);
    }

    fn end(&self, reason: &str) {
        let mut e = lock(&self.ending);
        if e.is_none() {
            *e = Some(reason.to_string());
        }
        self.stop.store(true, Ordering::SeqCst);
        self.ready.notify_all();
    }
}

impl Host {
    /// Takes `config`, or says every reason why not (the previous configuration stays).
    fn configure(&self, config: &ComponentConfig) -> Result<(), (tonic::Code, String)> {
        let invalid = |why: String| (tonic::Code::InvalidArgument, why);
        let settings =
            ObserverSettings::from_json(&config.config_json).map_err(|e| invalid(e.to_string()))?;
        if let Some(a) = lock(&self.active).as_ref() {
            if a.observer.in_trial() {
                if a.settings == settings {
                    return Ok(());
                }
                return Err((
                    tonic::Code::FailedPrecondition,
                    "a trial is running; the component's config can change between trials \
                     (stop the recording first)"
                        .into(),
                ));
            }
        }
        // The policy and settings load on a thread of their own with a deadline, and outside
        // the lock the session thread needs: tracking goes on meanwhile.
        let (tx, rx) = std::sync::mpsc::channel();
        let (loader, for_loader) = (Arc::clone(&self.loader), settings.clone());
        std::thread::Builder::new()
            .name("observer-config".into())
            .spawn(move || {
                let _ = tx.send(loader(&for_loader));
            })
            .map_err(|e| invalid(format!("cannot start loading: {e}")))?;
        let wait = Duration::from_secs_f64(self.guard.config_load_s);
        let prepared = match rx.recv_timeout(wait) {
            Ok(r) => r.map_err(|e| invalid(e.to_string()))?,
            Err(_) => {
                return Err(invalid(format!(
                    "loading the policy and settings took longer than {} s (does a path name a \
                     FIFO, a device, or a disk that hangs?); nothing was changed",
                    self.guard.config_load_s
                )))
            }
        };
        let expected = Expected {
            tank_cm: crate::TANK_CM as u32,
            fps: prepared.trained_fps,
            accept_other_fps: settings.accept_other_fps,
        };
        let observer = Observer::new(
            prepared.live,
            prepared.task,
            settings.out.clone(),
            settings.ids(),
            expected,
            settings.follow_recording,
            self.fallback_dir.clone(),
            prepared.pilot,
        )
        .map_err(|e| invalid(e.to_string()))?;
        let mut active = lock(&self.active);
        if active.as_ref().is_some_and(|a| a.observer.in_trial()) {
            return Err((
                tonic::Code::FailedPrecondition,
                "a trial started while the configuration loaded; it can change between trials"
                    .into(),
            ));
        }
        // The same output directory keeps its lock, the same sink its robot program's
        // connection. What is new is taken before the old is let go, so a refusal (a directory
        // in use, a port taken) leaves the component as it was configured.
        let (same_out, same_sink) = active.as_ref().map_or((false, false), |a| {
            (
                a.settings.out == settings.out,
                a.settings.robot_sink == settings.robot_sink,
            )
        });
        let new_lock = if same_out {
            None
        } else {
            Some(
                fishprobe_io::DirLock::acquire(&settings.out, "live biotracker")
                    .map_err(|e| invalid(e.to_string()))?,
            )
        };
        let old = active.take();
        let new_sink = if same_sink {
            None
        } else {
            let started = TcpListener::bind(settings.robot_sink)
                .map_err(|e| format!("robot sink on {}: {e}", settings.robot_sink))
                .and_then(|l| {
                    RobotSink::start(l, settings.robot_sink_token.clone())
                        .map_err(|e| e.to_string())
                });
            match started {
                Ok(s) => Some(s),
                Err(why) => {
                    *active = old;
                    return Err(invalid(why));
                }
            }
        };
        let (out_lock, sink) = match (old, new_lock, new_sink) {
            (Some(a), l, s) => (l.unwrap_or(a.lock), s.unwrap_or(a.sink)),
            (None, Some(l), Some(s)) => (l, s),
            (None, _, _) => return Err(invalid("internal: nothing to configure from".into())),
        };
        // A kept sink takes the new token for the next program that connects.
        sink.set_token(settings.robot_sink_token.clone());
        *lock(&self.core) = settings.core;
        self.log(&format!(
            "configured ({}): policy {}, robot id {}, fish ids {:?}, robot sink {}, core {}, \
             trials {}",
            clip(&config.id, 200),
            clip(&settings.policy, 500),
            settings.robot_id,
            settings.fish_ids,
            sink.local_addr(),
            settings.core,
            if settings.follow_recording {
                "follow the recording"
            } else {
                "start at the first update"
            }
        ));
        *active = Some(Active {
            settings,
            lock: out_lock,
            observer,
            sink,
        });
        Ok(())
    }
}

impl ObserverCalls for Host {
    fn set_config(&self, config: ComponentConfig) -> Result<(), Status> {
        let first = !self.answered_first.swap(true, Ordering::SeqCst);
        let Err((code, why)) = self.configure(&config) else {
            return Ok(());
        };
        let why = clip(&why, MAX_REASON_CHARS);
        if first && code == tonic::Code::InvalidArgument {
            // BioTracker's core would drop the component for good: answer success, stay
            // unconfigured (the robot stopped), and say why where the lab looks.
            let line = format!(
                "the first configuration is refused, the robot stays stopped until a corrected \
                 entry arrives (edit the component's config in BioTracker): {why}"
            );
            self.log(&line);
            let _ = writeln!(std::io::stderr(), "fishprobe: {line}");
            return Ok(());
        }
        self.log(&format!("set_config refused: {why}"));
        Err(Status::new(code, why))
    }

    fn update(&self, experiment: Experiment) -> Result<(), Status> {
        if self.stop.load(Ordering::SeqCst) {
            return Err(Status::unavailable("the observer is ending"));
        }
        let mut q = lock(&self.queue);
        if q.updates.len() >= self.guard.queue {
            q.updates.pop_front();
            q.dropped += 1;
        }
        q.updates.push_back(experiment);
        drop(q);
        self.ready.notify_one();
        Ok(())
    }
}

/// How the component ended.
#[derive(Debug, Clone, PartialEq)]
pub struct ComponentEnd {
    /// Why.
    pub reason: String,
    /// Trials that could not be written anywhere.
    pub unsaved: Vec<PathBuf>,
}

/// Runs the observer component: serves `biotracker.Observer` on `listener` until the core is
/// gone (heartbeat) or `stop` is set, with the log at `log` (appended). Returns why it ended.
pub fn run(
    listener: TcpListener,
    core: SocketAddr,
    loader: Box<Loader>,
    guard: ComponentGuard,
    log: Option<PathBuf>,
    fallback_dir: Option<PathBuf>,
    stop: Arc<AtomicBool>,
) -> Result<ComponentEnd, LiveError> {
    guard.validate()?;
    let log_file = match &log {
        Some(p) => Some(
            std::fs::OpenOptions::new()
                .create(true)
                .append(true)
                .open(p)
                .map_err(|e| LiveError::Write {
                    path: p.clone(),
                    what: e.to_string(),
                })?,
        ),
        None => None,
    };
    let addr = listener
        .local_addr()
        .map_err(|e| LiveError::Net(e.to_string()))?;
    let host = Arc::new(Host {
        loader: Arc::from(loader),
        answered_first: AtomicBool::new(false),
        guard: guard.clone(),
        fallback_dir,
        queue: Mutex::new(Queue::default()),
        ready: Condvar::new(),
        active: Mutex::new(None),
        log: Mutex::new(Log(log_file)),
        core: Mutex::new(core),
        ending: Mutex::new(None),
        stop: AtomicBool::new(false),
    });
    host.log(&format!(
        "observer listening on {addr}; core {core} until the config names one"
    ));
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .map_err(|e| LiveError::Net(format!("runtime: {e}")))?;
    let session = {
        let host = Arc::clone(&host);
        std::thread::Builder::new()
            .name("observer-session".into())
            .spawn(move || session_loop(&host))
            .map_err(|e| LiveError::Net(format!("session thread: {e}")))?
    };
    let service = grpc::observer_service(host.clone(), guard.max_message_bytes);
    let served = runtime.block_on(async {
        // The server runs until the runtime is dropped: no graceful shutdown, which would wait
        // for the core's connections to close (a hung core never closes them).
        let server = tokio::spawn(grpc::serve_with(
            listener,
            service,
            guard.connection_limits(),
            std::future::pending(),
        ));
        let h = Arc::clone(&host);
        let mut tick = tokio::time::interval(Duration::from_secs_f64(h.guard.heartbeat_s));
        let timeout = Duration::from_secs_f64(h.guard.heartbeat_timeout_s);
        let mut current = *lock(&h.core);
        let mut client = Client::lazy(current, timeout).ok();
        let mut failures = 0u32;
        loop {
            // The heartbeat's period, or sooner when the session ends the component.
            tokio::select! {
                _ = tick.tick() => {}
                () = wait_for_stop(&h) => {}
            }
            if stop.load(Ordering::SeqCst) {
                h.end("stopped");
            }
            if server.is_finished() {
                h.end("the gRPC server stopped");
                return match server.await {
                    Ok(r) => r,
                    Err(e) => Err(LiveError::Net(format!("gRPC server: {e}"))),
                };
            }
            if h.stop.load(Ordering::SeqCst) {
                return Ok(());
            }
            let now = *lock(&h.core);
            if now != current {
                current = now;
                client = Client::lazy(current, timeout).ok();
                failures = 0;
            }
            let ok = match &mut client {
                Some(c) => tokio::time::timeout(timeout, c.heartbeat())
                    .await
                    .is_ok_and(|r| r.is_ok()),
                None => false,
            };
            if ok {
                failures = 0;
            } else {
                failures += 1;
                if failures >= h.guard.heartbeat_failures {
                    h.end("tracker core gone");
                    return Ok(());
                }
            }
        }
    });
    // Dropping the runtime drops the server and its connections.
    drop(runtime);
    host.end("the component stopped");
    let _ = session.join();
    let reason = lock(&host.ending)
        .clone()
        .unwrap_or_else(|| "stopped".into());
    let unsaved = lock(&host.active)
        .as_mut()
        .map(|a| a.observer.unsaved())
        .unwrap_or_default();
    host.log(&format!("observer ends: {reason}"));
    served?;
    Ok(ComponentEnd { reason, unsaved })
}

/// The session thread: takes updates off the queue, runs the observer, feeds the sink.
/// Resolves once the component is ending (checked every 50 ms).
async fn wait_for_stop(h: &Host) {
    while !h.stop.load(Ordering::SeqCst) {
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
}

fn session_loop(host: &Host) {
    let mut last_update = Instant::now();
    let mut dropped_seen = 0u64;
    let mut events = Vec::new();
    loop {
        if let Some(why) = crate::shutdown::requested() {
            host.end(&why);
        }
        let next = {
            let mut q = lock(&host.queue);
            if q.updates.is_empty() && !host.stop.load(Ordering::SeqCst) {
                q = host
                    .ready
                    .wait_timeout(q, Duration::from_millis(20))
                    .map(|(g, _)| g)
                    .unwrap_or_else(|e| e.into_inner().0);
            }
            let dropped = q.dropped;
            (q.updates.pop_front(), dropped)
        };
        let mut active = lock(&host.active);
        if host.stop.load(Ordering::SeqCst) {
            if let Some(a) = active.as_mut() {
                let reason = lock(&host.ending)
                    .clone()
                    .unwrap_or_else(|| "stopped".into());
                a.observer.finish(&reason, &mut events);
                if !events.iter().any(|e| matches!(e, Event::Command(_))) {
                    // No trial to end: the robot program still hears why fishprobe goes.
                    events.push(Event::Command(Command::stop_outside_trial(0.0, &reason, 0)));
                }
                deliver(host, a, &mut events);
            }
            return;
        }
        let Some(a) = active.as_mut() else {
            continue;
        };
        match next {
            (Some(e), dropped) => {
                if dropped != dropped_seen {
                    dropped_seen = dropped;
                    a.observer
                        .note("updates_dropped_queue_full", dropped.into());
                }
                a.observer.set_robot_connected(a.sink.connected());
                // Only a new tracked frame is a sign of life: it restarts the silence clock
                // and feeds the robot program's watchdog. A repeated or backwards frame number
                // does neither, so a tracker whose counter sticks stops the robot.
                if a.observer.on_update(&e, &mut events) {
                    last_update = Instant::now();
                    let frame = e.last_features.as_ref().map_or(0, |f| f.frame_number);
                    a.sink.tick(f64::from(frame) / f64::from(e.target_fps));
                } else {
                    a.observer
                        .on_silence(last_update.elapsed().as_secs_f64(), &mut events);
                }
            }
            (None, _) => a
                .observer
                .on_silence(last_update.elapsed().as_secs_f64(), &mut events),
        }
        deliver(host, a, &mut events);
    }
}

fn deliver(host: &Host, a: &mut Active, events: &mut Vec<Event>) {
    for why in a.sink.take_dropped() {
        host.log(&why);
    }
    for e in events.drain(..) {
        match e {
            Event::Command(m) => a.sink.command(&m),
            Event::Log(l) => host.log(&l),
            Event::Started(_) | Event::Ended(_) => {}
        }
    }
}
