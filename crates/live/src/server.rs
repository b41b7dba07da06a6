//! The bridge's TCP side: one trial per connection, one connection at a time.
//!
//! Lines longer than `max_message_bytes` are dropped (the robot is stopped and told why);
//! malformed lines stop the robot; a client that goes quiet for `stale_s` of wall-clock time
//! gets a stop; a client that disconnects leaves a complete trial file of what was recorded.

use crate::error::LiveError;
use crate::protocol::{parse_client, to_line, ClientMsg, ServerMsg, PROTOCOL_VERSION};
use crate::session::{LiveConfig, Pilot, Session};
use fishprobe_sim::TaskParams;
use std::io::{BufRead, BufReader, ErrorKind, Read, Write};
use std::net::{SocketAddr, TcpListener, TcpStream};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

/// How the bridge serves.
#[derive(Debug, Clone)]
pub struct ServeOptions {
    /// Trial protocol and safety settings.
    pub live: LiveConfig,
    /// Goals and goal radius (evaluation goals).
    pub task: TaskParams,
    /// Where trial files go: `<out>/<Policy>__Real/` or `<out>/<Policy>__VirtualLab/`.
    pub out: PathBuf,
    /// Required in the hello when set (always set when listening beyond loopback).
    pub token: Option<String>,
    /// Stop after this many trials (None: serve until killed).
    pub max_trials: Option<usize>,
    /// The fish's label in trial files ("live guppy"; the virtual lab says "virtual guppy").
    pub fish_label: String,
}

/// What one connection produced.
#[derive(Debug, Clone, PartialEq)]
pub struct TrialOutcome {
    /// The trial file (None when the client never completed the handshake).
    pub file: Option<PathBuf>,
    /// Goals reached.
    pub goals_reached: u32,
    /// Whether the trial ran to its end (else the client left early).
    pub complete: bool,
    /// Frames recorded.
    pub frames: usize,
}

fn send(stream: &mut TcpStream, m: &ServerMsg) -> std::io::Result<()> {
    stream.write_all(to_line(m).as_bytes())
}

/// What one read produced.
enum Line {
    /// A complete line.
    Text(String),
    /// A line longer than the limit was dropped (its length so far).
    TooLong(usize),
    /// A line that is not UTF-8.
    Binary,
    /// Nothing complete within the read timeout (a partial line is kept).
    Timeout,
    /// The peer closed.
    Closed,
}

/// Lines of at most `max` bytes from a stream with a read timeout. A partial line survives a
/// timeout; an oversized one is discarded up to its newline without being stored.
struct LineReader {
    r: BufReader<TcpStream>,
    buf: Vec<u8>,
    max: usize,
    discarding: Option<usize>,
}

impl LineReader {
    fn new(s: TcpStream, max: usize) -> Self {
        Self {
            r: BufReader::new(s),
            buf: Vec::new(),
            max,
            discarding: None,
        }
    }

    fn next(&mut self) -> std::io::Result<Line> {
        loop {
            let available = match self.r.fill_buf() {
                Ok(b) => b,
                Err(e) if matches!(e.kind(), ErrorKind::WouldBlock | ErrorKind::TimedOut) => {
                    return Ok(Line::Timeout)
                }
                Err(e) if e.kind() == ErrorKind::Interrupted => continue,
                Err(e) => return Err(e),
            };
            if available.is_empty() {
                return Ok(Line::Closed);
            }
            let newline = available.iter().position(|&b| b == b'\n');
            let take = newline.map_or(available.len(), |i| i + 1);
            let chunk = &available[..newline.unwrap_or(available.len())];
            match &mut self.discarding {
                Some(n) => *n += chunk.len(),
                None if self.buf.len() + chunk.len() > self.max => {
                    self.discarding = Some(self.buf.len() + chunk.len());
                    self.buf.clear();
                }
                None => self.buf.extend_from_slice(chunk),
            }
            self.r.consume(take);
            if newline.is_some() {
                if let Some(n) = self.discarding.take() {
                    return Ok(Line::TooLong(n));
                }
                let bytes = std::mem::take(&mut self.buf);
                return Ok(match String::from_utf8(bytes) {
                    Ok(s) => Line::Text(s),
                    Err(_) => Line::Binary,
                });
            }
        }
    }
}

/// Whether an address is on this machine only.
pub fn is_loopback(addr: &SocketAddr) -> bool {
    addr.ip().is_loopback()
}

/// Serves trials on `listener` until `max_trials` are done; `pilot` makes the pilot of each
/// trial.
pub fn serve(
    listener: &TcpListener,
    opts: &ServeOptions,
    pilot: &mut dyn FnMut() -> Result<Box<dyn Pilot>, LiveError>,
    mut on_trial: impl FnMut(&TrialOutcome),
) -> Result<Vec<TrialOutcome>, LiveError> {
    opts.live.validate()?;
    let mut outcomes = Vec::new();
    let mut n = 0usize;
    while opts.max_trials.is_none_or(|m| outcomes.len() < m) {
        let (stream, _) = listener
            .accept()
            .map_err(|e| LiveError::Net(format!("accept: {e}")))?;
        let o = handle(stream, opts, pilot()?, &mut n)?;
        on_trial(&o);
        if o.file.is_some() {
            outcomes.push(o);
        }
    }
    Ok(outcomes)
}

fn next_free(dir: &Path, n: &mut usize) -> PathBuf {
    loop {
        let p = dir.join(format!("trial_{:03}.hdf5", *n));
        *n += 1;
        if !p.exists() {
            return p;
        }
    }
}

fn handle(
    mut stream: TcpStream,
    opts: &ServeOptions,
    pilot: Box<dyn Pilot>,
    n: &mut usize,
) -> Result<TrialOutcome, LiveError> {
    let cfg = &opts.live;
    let poll = Duration::from_secs_f64((cfg.stale_s / 2.0).clamp(0.01, 1.0));
    let _ = stream.set_nodelay(true);
    let _ = stream.set_read_timeout(Some(poll));
    let mut reader = LineReader::new(
        stream
            .try_clone()
            .map_err(|e| LiveError::Net(e.to_string()))?,
        cfg.max_message_bytes,
    );
    let nothing = TrialOutcome {
        file: None,
        goals_reached: 0,
        complete: false,
        frames: 0,
    };
    // Handshake (10 s to say hello).
    let started = Instant::now();
    let hello = loop {
        match reader.next() {
            Ok(Line::Text(l)) if l.trim().is_empty() => continue,
            Ok(Line::Text(l)) => break parse_client(&l),
            Ok(Line::Timeout) if started.elapsed() < Duration::from_secs(10) => continue,
            Ok(Line::Closed) | Err(_) => return Ok(nothing),
            Ok(Line::Timeout) => break Err("no hello within 10 s".into()),
            Ok(Line::TooLong(_)) | Ok(Line::Binary) => break Err("unreadable hello".into()),
        }
    };
    let refuse = |stream: &mut TcpStream, reason: String| {
        let _ = send(stream, &ServerMsg::Error { reason });
    };
    let (source, sync) = match hello {
        Ok(ClientMsg::Hello {
            protocol,
            world_size_cm,
            tracking_hz,
            source,
            token,
            sync,
        }) => {
            if protocol != PROTOCOL_VERSION {
                refuse(
                    &mut stream,
                    format!(
                        "protocol {protocol} not supported (this bridge speaks {PROTOCOL_VERSION})"
                    ),
                );
                return Ok(nothing);
            }
            if (world_size_cm[0] - 100.0).abs() > 0.5 || (world_size_cm[1] - 100.0).abs() > 0.5 {
                refuse(
                    &mut stream,
                    format!("tank {world_size_cm:?} cm; the policy was trained for 100 x 100"),
                );
                return Ok(nothing);
            }
            if !(tracking_hz.is_finite() && tracking_hz > 0.0) {
                refuse(&mut stream, format!("tracking rate {tracking_hz} Hz"));
                return Ok(nothing);
            }
            if opts.token.is_some() && token != opts.token {
                refuse(&mut stream, "missing or wrong token".into());
                return Ok(nothing);
            }
            if source != "lab" && source != "virtual_lab" {
                refuse(
                    &mut stream,
                    format!("source `{source}`: expected \"lab\" or \"virtual_lab\""),
                );
                return Ok(nothing);
            }
            (source, sync)
        }
        Ok(other) => {
            refuse(&mut stream, format!("expected hello, got {other:?}"));
            return Ok(nothing);
        }
        Err(e) => {
            refuse(&mut stream, e);
            return Ok(nothing);
        }
    };
    let mut session = Session::new(cfg.clone(), opts.task.clone(), pilot, &source)?;
    let arm = if source == "virtual_lab" {
        "VirtualLab"
    } else {
        "Real"
    };
    let dir = opts.out.join(format!("{}__{arm}", session.policy()));
    std::fs::create_dir_all(&dir).map_err(|e| LiveError::Write {
        path: dir.clone(),
        what: e.to_string(),
    })?;
    let file = next_free(&dir, n);
    let welcome = ServerMsg::Welcome {
        protocol: PROTOCOL_VERSION,
        policy: session.policy(),
        habituation_s: cfg.habituation_s,
        release_s: cfg.release_s,
        control_s: cfg.control_s,
        command_hz: cfg.command_hz,
    };
    let mut alive = send(&mut stream, &welcome).is_ok();
    let mut last_msg = Instant::now();
    while alive && !session.is_done() {
        let replies = match reader.next() {
            Ok(Line::Text(l)) if l.trim().is_empty() => Vec::new(),
            Ok(Line::Text(l)) => {
                last_msg = Instant::now();
                match parse_client(&l) {
                    Ok(ClientMsg::End) => break,
                    Ok(m) => {
                        let t = match &m {
                            ClientMsg::Frame { t, .. } => Some(*t),
                            _ => None,
                        };
                        let mut r = session.on_message(m);
                        if let (true, Some(t)) = (sync, t) {
                            if !session.is_done() {
                                r.push(ServerMsg::Ack { t });
                            }
                        }
                        r
                    }
                    Err(e) => session.on_malformed(&e),
                }
            }
            Ok(Line::TooLong(len)) => {
                last_msg = Instant::now();
                session.on_malformed(&format!(
                    "message of more than {} bytes ({len} read) dropped",
                    cfg.max_message_bytes
                ))
            }
            Ok(Line::Binary) => session.on_malformed("not UTF-8"),
            Ok(Line::Timeout) if sync => Vec::new(),
            Ok(Line::Timeout) => session.on_silence(last_msg.elapsed().as_secs_f64()),
            Ok(Line::Closed) | Err(_) => break,
        };
        for r in &replies {
            if send(&mut stream, r).is_err() {
                alive = false;
            }
        }
    }
    let complete = session.is_done();
    let label = if session.kind() == fishprobe_io::TrialKind::Virtual {
        "virtual guppy"
    } else {
        opts.fish_label.as_str()
    };
    fishprobe_io::write_trial(&file, &session.trial_file(label)).map_err(|e| LiveError::Write {
        path: file.clone(),
        what: e.to_string(),
    })?;
    if alive {
        let _ = send(
            &mut stream,
            &ServerMsg::Done {
                file: file.display().to_string(),
                goals_reached: session.goals_reached(),
            },
        );
    }
    // Drain what the client still sends, briefly, so it sees `done` before the close.
    let _ = stream.set_read_timeout(Some(Duration::from_millis(50)));
    let mut sink = [0u8; 1024];
    let _ = stream.read(&mut sink);
    Ok(TrialOutcome {
        file: Some(file),
        goals_reached: session.goals_reached(),
        complete,
        frames: session.frames(),
    })
}
