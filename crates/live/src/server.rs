//! The bridge's TCP side: one trial at a time, any number of connections knocking.
//!
//! Every connection says hello in its own thread, within [`BridgeGuard::handshake_s`]; only an
//! authenticated hello claims the trial slot, so a peer that connects and says nothing (or
//! trickles a byte at a time) never blocks a real lab client, and at most
//! [`BridgeGuard::max_pending`] connections wait at once (the oldest is dropped beyond). While a
//! trial runs, a new connection is refused at once with a "busy" error.
//!
//! During a trial, lines longer than `max_message_bytes` are dropped (the robot is stopped and
//! told why); malformed lines stop the robot; the silence stop counts from the last complete,
//! valid tracking frame, so blank lines, partial lines and garbage never keep a robot going. A
//! client that disconnects leaves a complete trial file of every frame it sent, and a trial
//! that cannot be written is kept (see [`crate::keep`]).

use crate::error::LiveError;
use crate::host::{
    Ended, HostConfig, Reactions, SourceEvent, Started, TrackerSource, TrialHost, TrialOutcome,
    TrialStart,
};
use crate::lines::{Line, LineReader};
use crate::protocol::{parse_client, to_line, ClientMsg, ServerMsg, PROTOCOL_VERSION};
use crate::session::LiveConfig;
use crate::track::{Command, Frame};
use fishprobe_io::TrialKind;
use fishprobe_sim::params::ConfigError;
use fishprobe_sim::{Controller, TaskParams};
use std::collections::VecDeque;
use std::io::{Read, Write};
use std::net::{SocketAddr, TcpListener, TcpStream};
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{mpsc, Mutex};
use std::time::{Duration, Instant};

/// How the bridge defends itself against peers (not part of the trial protocol).
#[derive(Debug, Clone, PartialEq)]
pub struct BridgeGuard {
    /// Time a new connection has to send a valid hello, in seconds (choice: 5 s; a lab client
    /// says hello at once). Counted from the connection, not reset by partial input.
    pub handshake_s: f64,
    /// Connections allowed to wait for their hello at once (choice: 32); beyond, the oldest
    /// waiting one is dropped, so a flood of idle connections cannot lock out a lab client.
    pub max_pending: usize,
    /// Where a trial goes when it cannot be written under `out` (None: the system's temporary
    /// directory, `fishprobe-unsaved/`).
    pub fallback_dir: Option<PathBuf>,
}

impl Default for BridgeGuard {
    fn default() -> Self {
        Self {
            handshake_s: 5.0,
            max_pending: 32,
            fallback_dir: None,
        }
    }
}

/// How the bridge serves.
#[derive(Debug, Clone)]
pub struct ServeOptions {
    /// Trial protocol and safety settings.
    pub live: LiveConfig,
    /// Goals and goal radius (evaluation goals).
    pub task: TaskParams,
    /// Where trial files go: `<out>/<Policy>__Real/` or `<out>/<Policy>__VirtualLab/`.
    pub out: PathBuf,
    /// Required in the hello when set (always set when listening beyond loopback); never
    /// empty.
    pub token: Option<String>,
    /// Stop after this many trials (None: serve until killed).
    pub max_trials: Option<usize>,
    /// The fish's label in trial files ("live guppy"; the virtual lab says "virtual guppy").
    pub fish_label: String,
    /// Defences against peers.
    pub guard: BridgeGuard,
}

impl ServeOptions {
    /// Checks the settings before the bridge listens.
    pub fn validate(&self) -> Result<(), LiveError> {
        self.live.validate()?;
        if self.token.as_deref().is_some_and(|t| t.trim().is_empty()) {
            return Err(ConfigError::new("bridge", "token", "\"\"", "must not be empty").into());
        }
        let g = &self.guard;
        if !(g.handshake_s.is_finite() && g.handshake_s > 0.0 && g.handshake_s <= 600.0) {
            return Err(ConfigError::new(
                "bridge",
                "handshake_s",
                g.handshake_s,
                "must lie in (0, 600]",
            )
            .into());
        }
        if !(1..=4096).contains(&g.max_pending) {
            return Err(ConfigError::new(
                "bridge",
                "max_pending",
                g.max_pending,
                "must lie in [1, 4096]",
            )
            .into());
        }
        Ok(())
    }
}

fn send(stream: &mut TcpStream, m: &ServerMsg) -> std::io::Result<()> {
    stream.write_all(to_line(m).as_bytes())
}

fn refuse(mut stream: TcpStream, reason: String) {
    let _ = stream.set_write_timeout(Some(Duration::from_secs(1)));
    let _ = send(&mut stream, &ServerMsg::Error { reason });
    let _ = stream.shutdown(std::net::Shutdown::Both);
}

/// Whether an address is on this machine only.
pub fn is_loopback(addr: &SocketAddr) -> bool {
    addr.ip().is_loopback()
}

/// Compares tokens in time independent of where they differ.
pub(crate) fn same_token(a: &str, b: &str) -> bool {
    a.len() == b.len() && a.bytes().zip(b.bytes()).fold(0u8, |d, (x, y)| d | (x ^ y)) == 0
}

/// A connection whose hello was accepted and that holds the trial slot.
struct Admitted {
    stream: TcpStream,
    reader: LineReader,
    source: String,
    sync: bool,
}

/// Connections waiting for their hello, so that the oldest can be dropped and all can be
/// closed when the bridge stops.
#[derive(Default)]
struct Waiting {
    next: u64,
    conns: VecDeque<(u64, TcpStream)>,
}

/// What the threads of one `serve` share.
struct Shared<'a> {
    opts: &'a ServeOptions,
    busy: AtomicBool,
    stop: AtomicBool,
    waiting: Mutex<Waiting>,
    accept_error: Mutex<Option<String>>,
}

/// Serves trials on `listener` until `max_trials` are done; `pilot` makes the pilot of each
/// trial.
pub fn serve(
    listener: &TcpListener,
    opts: &ServeOptions,
    pilot: &mut dyn FnMut() -> Result<Box<dyn Controller>, LiveError>,
    mut on_trial: impl FnMut(&TrialOutcome),
) -> Result<Vec<TrialOutcome>, LiveError> {
    opts.validate()?;
    let mut host = TrialHost::new(
        HostConfig {
            live: opts.live.clone(),
            task: opts.task.clone(),
            out: opts.out.clone(),
            fish_label: opts.fish_label.clone(),
            fallback_dir: opts.guard.fallback_dir.clone(),
        },
        pilot,
    )?;
    // A pilot that cannot be made, or an output directory holding another policy's trials
    // under its name, is refused before the bridge listens.
    host.check_pilot()?;
    listener
        .set_nonblocking(true)
        .map_err(|e| LiveError::Net(format!("listener: {e}")))?;
    let shared = Shared {
        opts,
        busy: AtomicBool::new(false),
        stop: AtomicBool::new(false),
        waiting: Mutex::new(Waiting::default()),
        accept_error: Mutex::new(None),
    };
    let (tx, rx) = mpsc::channel::<Admitted>();
    let result = std::thread::scope(|scope| {
        let sh = &shared;
        scope.spawn(move || accept_loop(listener, sh, tx, scope));
        let mut outcomes = Vec::new();
        let r = loop {
            if opts.max_trials.is_some_and(|m| outcomes.len() >= m) {
                break Ok(outcomes);
            }
            if crate::shutdown::requested().is_some() {
                break Ok(outcomes);
            }
            let adm = match rx.recv_timeout(Duration::from_millis(100)) {
                Ok(a) => a,
                Err(mpsc::RecvTimeoutError::Timeout) => continue,
                Err(mpsc::RecvTimeoutError::Disconnected) => {
                    let why = sh.accept_error.lock().map(|e| e.clone()).ok().flatten();
                    break Err(LiveError::Net(format!(
                        "accept: {}",
                        why.unwrap_or_else(|| "the listener stopped".into())
                    )));
                }
            };
            let mut conn = Connection::new(adm, &opts.live, &sh.busy);
            crate::host::drive(&mut host, &mut conn);
            sh.busy.store(false, Ordering::SeqCst);
            let o = conn.outcome();
            on_trial(&o);
            outcomes.push(o);
        };
        sh.stop.store(true, Ordering::SeqCst);
        // Whoever was admitted meanwhile is told why nothing happens.
        while let Ok(adm) = rx.recv_timeout(Duration::from_millis(50)) {
            refuse(adm.stream, "the bridge is shutting down".into());
        }
        r
    });
    let _ = listener.set_nonblocking(false);
    let unsaved = host.unsaved();
    if !unsaved.is_empty() {
        return Err(LiveError::Write {
            path: unsaved[0].clone(),
            what: format!(
                "{} trial(s) could not be written anywhere and are lost when the bridge exits",
                unsaved.len()
            ),
        });
    }
    result
}

fn accept_loop<'scope, 'env>(
    listener: &'env TcpListener,
    sh: &'scope Shared<'scope>,
    tx: mpsc::Sender<Admitted>,
    scope: &'scope std::thread::Scope<'scope, 'env>,
) {
    loop {
        if sh.stop.load(Ordering::SeqCst) {
            if let Ok(mut w) = sh.waiting.lock() {
                for (_, c) in w.conns.drain(..) {
                    let _ = c.shutdown(std::net::Shutdown::Both);
                }
            }
            return;
        }
        let stream = match listener.accept() {
            Ok((s, _)) => s,
            Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => {
                std::thread::sleep(Duration::from_millis(10));
                continue;
            }
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => continue,
            Err(e) if matches!(e.raw_os_error(), Some(23 | 24)) => {
                // Out of file descriptors: wait for connections to end rather than stop.
                std::thread::sleep(Duration::from_millis(100));
                continue;
            }
            Err(e) => {
                if let Ok(mut slot) = sh.accept_error.lock() {
                    *slot = Some(e.to_string());
                }
                return;
            }
        };
        let _ = stream.set_nonblocking(false);
        if sh.busy.load(Ordering::SeqCst) {
            refuse(
                stream,
                "busy: a trial is running on this bridge; connect again when it has ended".into(),
            );
            continue;
        }
        let Ok(watch) = stream.try_clone() else {
            continue;
        };
        let id = {
            let Ok(mut w) = sh.waiting.lock() else {
                return;
            };
            while w.conns.len() >= sh.opts.guard.max_pending {
                if let Some((_, oldest)) = w.conns.pop_front() {
                    let _ = oldest.shutdown(std::net::Shutdown::Both);
                }
            }
            w.next += 1;
            let id = w.next;
            w.conns.push_back((id, watch));
            id
        };
        let tx = tx.clone();
        scope.spawn(move || {
            let admitted = handshake(stream, sh);
            if let Ok(mut w) = sh.waiting.lock() {
                w.conns.retain(|(i, _)| *i != id);
            }
            if let Some(a) = admitted {
                if let Err(mpsc::SendError(a)) = tx.send(a) {
                    refuse(a.stream, "the bridge is shutting down".into());
                }
            }
        });
    }
}

/// Reads and checks the hello within the deadline; claims the trial slot for a valid one.
fn handshake(stream: TcpStream, sh: &Shared<'_>) -> Option<Admitted> {
    let opts = sh.opts;
    let deadline = Instant::now() + Duration::from_secs_f64(opts.guard.handshake_s);
    let _ = stream.set_nodelay(true);
    let _ = stream.set_read_timeout(Some(Duration::from_millis(100)));
    let mut reader = LineReader::new(stream.try_clone().ok()?, opts.live.max_message_bytes);
    let hello = loop {
        if Instant::now() >= deadline {
            refuse(
                stream,
                format!("no hello within {} s", opts.guard.handshake_s),
            );
            return None;
        }
        match reader.next() {
            Ok(Line::Text(l)) if l.trim().is_empty() => {}
            Ok(Line::Text(l)) => break parse_client(&l).map_err(|e| e.to_string()),
            Ok(Line::Partial | Line::Timeout) => {}
            Ok(Line::Closed) | Err(_) => return None,
            Ok(Line::TooLong(_) | Line::Binary) => break Err("unreadable hello".into()),
        }
    };
    let (source, sync) = match check_hello(hello, opts) {
        Ok(ok) => ok,
        Err(reason) => {
            refuse(stream, reason);
            return None;
        }
    };
    if sh
        .busy
        .compare_exchange(false, true, Ordering::SeqCst, Ordering::SeqCst)
        .is_err()
    {
        refuse(
            stream,
            "busy: a trial is running on this bridge; connect again when it has ended".into(),
        );
        return None;
    }
    Some(Admitted {
        stream,
        reader,
        source,
        sync,
    })
}

/// The hello's source and lockstep flag, or why it is refused.
fn check_hello(
    hello: Result<ClientMsg, String>,
    opts: &ServeOptions,
) -> Result<(String, bool), String> {
    let ClientMsg::Hello {
        protocol,
        world_size_cm,
        tracking_hz,
        source,
        token,
        sync,
    } = hello?
    else {
        return Err("expected hello".into());
    };
    if let Some(want) = &opts.token {
        if !token.as_deref().is_some_and(|t| same_token(t, want)) {
            return Err("missing or wrong token".into());
        }
    }
    if protocol != PROTOCOL_VERSION {
        return Err(format!(
            "protocol {protocol} not supported (this bridge speaks {PROTOCOL_VERSION})"
        ));
    }
    if world_size_cm
        .iter()
        .any(|s| (s - crate::TANK_CM).abs() > 0.5)
    {
        return Err(format!(
            "tank {world_size_cm:?} cm; the policy was trained for {0} x {0}",
            crate::TANK_CM
        ));
    }
    if !(tracking_hz.is_finite() && tracking_hz > 0.0) {
        return Err(format!("tracking rate {tracking_hz} Hz"));
    }
    match source.as_str() {
        "virtual_lab" => Ok((source, sync)),
        "lab" if sync => Err(
            "\"sync\": true is for the virtual lab only: a live lab streams frames, and the \
             bridge's silence stop must protect its robot"
                .into(),
        ),
        "lab" => Ok((source, false)),
        _ => Err(format!(
            "source `{source}`: expected \"lab\" or \"virtual_lab\""
        )),
    }
}

/// One admitted connection as a tracker source: its hello begins a trial, its lines are
/// frames (or malformed input, or silence), its `end` or its leaving ends the trial; the
/// trial's commands, lockstep acks, warnings and `done` go back to it.
struct Connection<'a> {
    stream: TcpStream,
    reader: LineReader,
    /// The trial to begin (taken at the first event).
    start: Option<TrialStart>,
    sync: bool,
    /// The silence stop applies (everything but the virtual lab in lockstep).
    watch_silence: bool,
    /// When the last complete, valid frame (or the welcome) came.
    last_frame: Instant,
    /// Frames the session had taken before the current one.
    max_message_bytes: usize,
    /// The client still reads.
    alive: bool,
    busy: &'a AtomicBool,
    cfg: &'a LiveConfig,
    outcome: Option<TrialOutcome>,
    /// The connection is finished with (refused, or the trial kept).
    over: bool,
}

impl<'a> Connection<'a> {
    fn new(adm: Admitted, cfg: &'a LiveConfig, busy: &'a AtomicBool) -> Self {
        let Admitted {
            mut stream,
            reader,
            source,
            sync,
        } = adm;
        let poll = Duration::from_secs_f64((cfg.stale_s / 5.0).clamp(0.01, 0.2));
        let _ = reader.get_ref().set_read_timeout(Some(poll));
        let _ = stream.set_write_timeout(Some(Duration::from_secs(2)));
        let kind = if source == "virtual_lab" {
            TrialKind::Virtual
        } else {
            TrialKind::Real
        };
        // Without a live robot (the virtual lab in lockstep) a slow client is no danger.
        let watch_silence = !(sync && kind == TrialKind::Virtual);
        let _ = &mut stream;
        Self {
            stream,
            reader,
            start: Some(TrialStart {
                kind,
                stem: None,
                origin: None,
                notes: Vec::new(),
                checkpoints: watch_silence,
            }),
            sync,
            watch_silence,
            last_frame: Instant::now(),
            max_message_bytes: cfg.max_message_bytes,
            alive: true,
            busy,
            cfg,
            outcome: None,
            over: false,
        }
    }

    fn send(&mut self, m: &ServerMsg) {
        if self.alive && send(&mut self.stream, m).is_err() {
            // A client that stopped listening may still have frames on the way: keep reading
            // them (into the trial file), only stop answering.
            self.alive = false;
        }
    }

    fn silence(&self) -> Option<SourceEvent> {
        self.watch_silence
            .then(|| SourceEvent::Silence(self.last_frame.elapsed().as_secs_f64()))
    }

    /// What the connection produced.
    fn outcome(self) -> TrialOutcome {
        self.outcome.unwrap_or(TrialOutcome {
            file: None,
            goals_reached: 0,
            complete: false,
            frames: 0,
            warning: Some("the trial did not begin".into()),
        })
    }
}

impl Reactions for Connection<'_> {
    fn command(&mut self, c: Command) {
        self.send(&ServerMsg::Command(c));
    }

    fn started(&mut self, s: &Started) {
        let cfg = self.cfg;
        let welcome = ServerMsg::Welcome {
            protocol: PROTOCOL_VERSION,
            policy: s.policy.clone(),
            habituation_s: cfg.habituation_s,
            release_s: cfg.release_s,
            control_s: cfg.control_s,
            command_hz: cfg.command_hz,
            fish_count: cfg.fish_count,
            policy_sha256: s.fingerprint.clone(),
        };
        self.send(&welcome);
        // The silence stop counts from the last complete, valid frame (or the welcome).
        self.last_frame = Instant::now();
    }

    fn refused(&mut self, why: &str) {
        self.send(&ServerMsg::Error {
            reason: why.to_string(),
        });
        let _ = self.stream.shutdown(std::net::Shutdown::Both);
        self.outcome = Some(TrialOutcome {
            file: None,
            goals_reached: 0,
            complete: false,
            frames: 0,
            warning: Some(why.to_string()),
        });
        self.over = true;
    }

    fn after_frame(&mut self, t: f64, accepted: bool, done: bool) {
        if accepted {
            self.last_frame = Instant::now();
        }
        if self.sync && !done {
            self.send(&ServerMsg::Ack { t });
        }
    }

    fn ended(&mut self, e: &Ended) {
        // The slot is free before `done` goes out, so a client that reconnects on `done` (the
        // virtual lab's next trial) is never told "busy".
        self.busy.store(false, Ordering::SeqCst);
        if e.reason.is_some() {
            // Ended before its time (fishprobe asked to stop): the robot holds still.
            let stop = ServerMsg::Command(e.stop.clone());
            self.send(&stop);
        }
        if let Some(w) = &e.outcome.warning {
            self.send(&ServerMsg::Error { reason: w.clone() });
        }
        let done = ServerMsg::Done {
            file: e
                .outcome
                .file
                .as_ref()
                .map_or_else(String::new, |f| f.display().to_string()),
            goals_reached: e.outcome.goals_reached,
        };
        self.send(&done);
        drain(&mut self.stream);
        self.outcome = Some(e.outcome.clone());
        self.over = true;
    }
}

impl TrackerSource for Connection<'_> {
    fn next_event(&mut self) -> Option<SourceEvent> {
        if let Some(start) = self.start.take() {
            return Some(SourceEvent::Begin(start));
        }
        loop {
            if self.over {
                return None;
            }
            let ev = match self.reader.next() {
                Ok(Line::Text(l)) if l.trim().is_empty() => self.silence(),
                Ok(Line::Text(l)) => Some(match parse_client(&l) {
                    Ok(ClientMsg::End) => return None,
                    Ok(ClientMsg::Frame { t, robot, fish }) => {
                        SourceEvent::Frame(Frame { t, robot, fish })
                    }
                    Ok(ClientMsg::Hello { .. }) => SourceEvent::Malformed("a second hello".into()),
                    Err(e) => SourceEvent::Malformed(e.to_string()),
                }),
                Ok(Line::TooLong(len)) => Some(SourceEvent::Malformed(format!(
                    "message of more than {} bytes ({len} read) dropped",
                    self.max_message_bytes
                ))),
                Ok(Line::Binary) => Some(SourceEvent::Malformed("not UTF-8".into())),
                Ok(Line::Partial | Line::Timeout) => self.silence(),
                Ok(Line::Closed) | Err(_) => return None,
            };
            if let Some(ev) = ev {
                return Some(ev);
            }
        }
    }
}

/// Reads what the client still sends, briefly, so it sees `done` before the close.
fn drain(stream: &mut TcpStream) {
    let _ = stream.set_read_timeout(Some(Duration::from_millis(50)));
    let mut sink = [0u8; 1024];
    let _ = stream.read(&mut sink);
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tokens_compare_whole() {
        assert!(same_token("s3cret", "s3cret"));
        assert!(!same_token("s3cret", "s3cre"));
        assert!(!same_token("s3cret", "s3creT"));
        assert!(!same_token("", "x"));
    }
}
