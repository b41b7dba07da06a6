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
use crate::keep::{Keeper, Kept};
use crate::lines::{Line, LineReader};
use crate::protocol::{parse_client, to_line, ClientMsg, ServerMsg, PROTOCOL_VERSION};
use crate::session::{LiveConfig, Session};
use fishprobe_io::{Arm, StudyLayout};
use fishprobe_sim::params::ConfigError;
use fishprobe_sim::{Controller, TaskParams};
use std::collections::VecDeque;
use std::io::{Read, Write};
use std::net::{SocketAddr, TcpListener, TcpStream};
use std::path::{Path, PathBuf};
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

/// What one connection produced.
#[derive(Debug, Clone, PartialEq)]
pub struct TrialOutcome {
    /// The trial file (None when it is held in memory because nothing could be written).
    pub file: Option<PathBuf>,
    /// Goals reached.
    pub goals_reached: u32,
    /// Whether the trial ran to its end (else the client left early).
    pub complete: bool,
    /// Frames recorded.
    pub frames: usize,
    /// What went wrong writing the trial (it went to the fallback, or stays in memory).
    pub warning: Option<String>,
}

fn send(stream: &mut TcpStream, m: &ServerMsg) -> std::io::Result<()> {
    stream.write_all(to_line(m).as_bytes())
}

fn refuse(mut stream: TcpStream, reason: String) {
    let _ = stream.set_write_timeout(Some(Duration::from_secs(1)));
    let _ = send(&mut stream, &ServerMsg::Error { reason });
    let _ = stream.shutdown(std::net::Shutdown::Both);
}

impl TrialOutcome {
    /// What a finished session produced, kept as `kept`.
    pub(crate) fn of(kept: &Kept, session: &Session) -> Self {
        Self {
            file: kept.written().map(Path::to_path_buf),
            goals_reached: session.goals_reached(),
            complete: session.is_done(),
            frames: session.frames(),
            warning: kept.warning(),
        }
    }
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
    check_provenance(&opts.out, pilot()?.as_ref())?;
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
    let mut keeper = Keeper::new(opts.guard.fallback_dir.clone());
    let (tx, rx) = mpsc::channel::<Admitted>();
    let result = std::thread::scope(|scope| {
        let sh = &shared;
        scope.spawn(move || accept_loop(listener, sh, tx, scope));
        let mut outcomes = Vec::new();
        let mut n = 0usize;
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
            let p = match pilot() {
                Ok(p) => p,
                Err(e) => {
                    refuse(adm.stream, format!("the bridge cannot make its pilot: {e}"));
                    break Err(e);
                }
            };
            let o = run_trial(adm, opts, p, &mut n, &mut keeper, &sh.busy);
            sh.busy.store(false, Ordering::SeqCst);
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
    keeper.retry();
    let unsaved = keeper.unsaved();
    if !unsaved.is_empty() {
        return Err(LiveError::Write {
            path: unsaved[0].to_path_buf(),
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

/// Refuses to add the pilot's trials to directories that hold another policy's under its
/// name (trials that record no fingerprint, from scripted pilots or older files, pass).
pub(crate) fn check_provenance(out: &Path, pilot: &dyn Controller) -> Result<(), LiveError> {
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
        // The bridge writes whole files only: one it cannot read was put there by hand.
        if let Some((f, e)) = p.unreadable.first() {
            return Err(LiveError::Mixed(format!(
                "{} cannot be read ({e}), so which policy drove it cannot be told",
                f.display()
            )));
        }
    }
    Ok(())
}

/// Runs one admitted trial to its end and keeps its file.
fn run_trial(
    adm: Admitted,
    opts: &ServeOptions,
    pilot: Box<dyn Controller>,
    n: &mut usize,
    keeper: &mut Keeper,
    busy: &AtomicBool,
) -> TrialOutcome {
    let Admitted {
        mut stream,
        mut reader,
        source,
        sync,
    } = adm;
    let cfg = &opts.live;
    let mut session = match Session::new(cfg.clone(), opts.task.clone(), pilot, &source) {
        Ok(s) => s,
        Err(e) => {
            refuse(stream, e.to_string());
            return TrialOutcome {
                file: None,
                goals_reached: 0,
                complete: false,
                frames: 0,
                warning: Some(e.to_string()),
            };
        }
    };
    let poll = Duration::from_secs_f64((cfg.stale_s / 5.0).clamp(0.01, 0.2));
    let _ = reader.get_ref().set_read_timeout(Some(poll));
    let _ = stream.set_write_timeout(Some(Duration::from_secs(2)));
    let arm = if source == "virtual_lab" {
        Arm::VirtualLab
    } else {
        Arm::Real
    };
    let dir = opts.out.join(StudyLayout::arm_dir_name(
        &StudyLayout::safe_name(&session.policy()),
        &arm,
    ));
    let file = next_free(&dir, n);
    // The descriptors the trial's file needs are held from now on, so connections arriving
    // during the trial cannot take them.
    if !keeper.reserve() {
        session.note(
            "file_descriptors",
            "none spare when the trial started; the file may fall back".into(),
        );
    }
    let label = if session.kind() == fishprobe_io::TrialKind::Virtual {
        "virtual guppy"
    } else {
        opts.fish_label.as_str()
    };
    let welcome = ServerMsg::Welcome {
        protocol: PROTOCOL_VERSION,
        policy: session.policy(),
        habituation_s: cfg.habituation_s,
        release_s: cfg.release_s,
        control_s: cfg.control_s,
        command_hz: cfg.command_hz,
        fish_count: cfg.fish_count,
        policy_sha256: session.fingerprint(),
    };
    let mut alive = send(&mut stream, &welcome).is_ok();
    // The silence stop counts from the last complete, valid frame (or the welcome).
    let mut last_frame = Instant::now();
    // Without a live robot (the virtual lab in lockstep) a slow client is no danger.
    let watch_silence = !(sync && source == "virtual_lab");
    while !session.is_done() {
        if let Some(why) = crate::shutdown::requested() {
            let stop = session.end_early(&why);
            if alive && send(&mut stream, &stop).is_err() {
                alive = false;
            }
            break;
        }
        let Some(replies) = replies_to(
            reader.next(),
            &mut session,
            sync,
            watch_silence,
            &mut last_frame,
            cfg.max_message_bytes,
        ) else {
            break;
        };
        // A client that stopped listening may still have frames on the way: keep reading
        // them (into the trial file), only stop answering.
        if alive {
            for r in &replies {
                if send(&mut stream, r).is_err() {
                    alive = false;
                    break;
                }
            }
        }
        // A live trial is checkpointed; the virtual lab in lockstep is reproducible, so a
        // lost one is run again instead.
        if watch_silence && session.checkpoint_due() {
            let _ = keeper.checkpoint(&file, session.checkpoint_file(label));
        }
    }
    let kept = keeper.keep(&file, session.trial_file(label));
    // Trials held in memory since an earlier failure get another chance.
    keeper.retry();
    // The slot is free before `done` goes out, so a client that reconnects on `done` (the
    // virtual lab's next trial) is never told "busy".
    busy.store(false, Ordering::SeqCst);
    let warning = kept.warning();
    if alive {
        if let Some(w) = &warning {
            let _ = send(&mut stream, &ServerMsg::Error { reason: w.clone() });
        }
        let _ = send(
            &mut stream,
            &ServerMsg::Done {
                file: kept
                    .written()
                    .map_or_else(String::new, |f| f.display().to_string()),
                goals_reached: session.goals_reached(),
            },
        );
    }
    drain(&mut stream);
    TrialOutcome::of(&kept, &session)
}

/// The bridge's answers to one read from the client: the session's replies (in lockstep with
/// the frame's ack); `None` when the client ended the trial or the connection closed.
/// `last_frame` moves when the session accepted a frame.
fn replies_to(
    read: std::io::Result<Line>,
    session: &mut Session,
    sync: bool,
    watch_silence: bool,
    last_frame: &mut Instant,
    max_message_bytes: usize,
) -> Option<Vec<ServerMsg>> {
    Some(match read {
        Ok(Line::Text(l)) if l.trim().is_empty() => silence(session, watch_silence, *last_frame),
        Ok(Line::Text(l)) => match parse_client(&l) {
            Ok(ClientMsg::End) => return None,
            Ok(m) => {
                let t = match &m {
                    ClientMsg::Frame { t, .. } => Some(*t),
                    _ => None,
                };
                let accepted = session.frames_accepted();
                let mut r = session.on_message(m);
                if session.frames_accepted() > accepted {
                    *last_frame = Instant::now();
                }
                if let (true, Some(t)) = (sync, t) {
                    if !session.is_done() {
                        r.push(ServerMsg::Ack { t });
                    }
                }
                r
            }
            Err(e) => session.on_malformed(&e.to_string()),
        },
        Ok(Line::TooLong(len)) => session.on_malformed(&format!(
            "message of more than {max_message_bytes} bytes ({len} read) dropped"
        )),
        Ok(Line::Binary) => session.on_malformed("not UTF-8"),
        Ok(Line::Partial | Line::Timeout) => silence(session, watch_silence, *last_frame),
        Ok(Line::Closed) | Err(_) => return None,
    })
}

fn silence(session: &mut Session, watch: bool, last_frame: Instant) -> Vec<ServerMsg> {
    if watch {
        session.on_silence(last_frame.elapsed().as_secs_f64())
    } else {
        Vec::new()
    }
}

/// Reads what the client still sends, briefly, so it sees `done` before the close.
fn drain(stream: &mut TcpStream) {
    let _ = stream.set_read_timeout(Some(Duration::from_millis(50)));
    let mut sink = [0u8; 1024];
    let _ = stream.read(&mut sink);
}

pub(crate) fn next_free(dir: &Path, n: &mut usize) -> PathBuf {
    loop {
        let p = dir.join(format!("trial_{:03}.hdf5", *n));
        *n += 1;
        if !p.exists() {
            return p;
        }
    }
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
