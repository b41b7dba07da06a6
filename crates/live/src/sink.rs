//! The robot sink: where the lab's robot program reads fishprobe's commands when the tracker
//! (BioTracker v4) is the one talking to fishprobe.
//!
//! fishprobe listens (loopback by default) and streams newline-delimited JSON to one robot
//! program: the live protocol's `command` messages (`docs/live-protocol.md`) and, on every
//! tracking frame, a `tick` (`{"type":"tick","t":12.04}`), so the robot side can stop on its
//! own when fishprobe falls silent (the documented watchdog: stop after
//! [`WATCHDOG_S`] without a line). A second program that connects while one is served is told
//! `busy` and closed. A program that connects (or reconnects) first gets the robot's current
//! state: the last command, or a stop when there was none. Off loopback the program must first
//! send `{"type":"robot","token":"..."}`.

use crate::lines::{Line, LineReader};
use crate::protocol::{to_line, ServerMsg};
use std::io::Write;
use std::net::{SocketAddr, TcpListener, TcpStream};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, PoisonError};
use std::time::{Duration, Instant};

/// A robot program should stop its robot when no line came for this long (s): two ticks at
/// the slowest tracking rate BioTracker runs at (4 Hz) and a dozen at the lab's 25 Hz.
pub const WATCHDOG_S: f64 = 0.5;

/// How long a write to the robot program may take before it is dropped (a program that does
/// not read its socket cannot be driven; choice: 0.2 s, a tenth of a second's ticks).
const WRITE_TIMEOUT: Duration = Duration::from_millis(200);

/// How long a program off loopback has to send its token.
const HANDSHAKE: Duration = Duration::from_secs(5);

/// One tick line.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(tag = "type", rename = "tick")]
pub struct Tick {
    /// The tracking frame's time (s).
    pub t: f64,
}

#[derive(Default)]
struct State {
    client: Option<TcpStream>,
    /// The last command sent, as its line: what a reconnecting program gets first.
    current: Option<String>,
}

struct Shared {
    state: Mutex<State>,
    stop: AtomicBool,
    token: Mutex<Option<String>>,
    /// Handshakes in progress (off loopback), at most [`MAX_HANDSHAKES`].
    handshakes: std::sync::atomic::AtomicUsize,
}

/// Robot programs that may be sending their token at once; more are refused at once, so idle
/// connections cannot hold the sink.
const MAX_HANDSHAKES: usize = 8;

/// The sink; see the module's docs. Dropping it stops listening and closes the client.
pub struct RobotSink {
    shared: Arc<Shared>,
    addr: SocketAddr,
    accept: Option<std::thread::JoinHandle<()>>,
}

impl std::fmt::Debug for RobotSink {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("RobotSink")
            .field("addr", &self.addr)
            .field("connected", &self.connected())
            .finish()
    }
}

fn stop_line() -> String {
    to_line(&ServerMsg::stop_outside_trial(0.0, "no command yet", 0))
}

impl RobotSink {
    /// Serves robot programs on `listener`. Off loopback a non-empty `token` is required.
    pub fn start(listener: TcpListener, token: Option<String>) -> Result<Self, crate::LiveError> {
        let addr = listener
            .local_addr()
            .map_err(|e| crate::LiveError::Net(format!("robot sink: {e}")))?;
        if token.as_deref().is_some_and(|t| t.trim().is_empty()) {
            return Err(crate::LiveError::Observer(
                "the robot sink's token is empty".into(),
            ));
        }
        if !addr.ip().is_loopback() && token.is_none() {
            return Err(crate::LiveError::Unsafe {
                addr: addr.to_string(),
            });
        }
        listener
            .set_nonblocking(true)
            .map_err(|e| crate::LiveError::Net(format!("robot sink: {e}")))?;
        let shared = Arc::new(Shared {
            state: Mutex::new(State::default()),
            stop: AtomicBool::new(false),
            token: Mutex::new(token),
            handshakes: std::sync::atomic::AtomicUsize::new(0),
        });
        let sh = Arc::clone(&shared);
        let accept = std::thread::Builder::new()
            .name("robot-sink".into())
            .spawn(move || accept_loop(&listener, &sh))
            .map_err(|e| crate::LiveError::Net(format!("robot sink thread: {e}")))?;
        Ok(Self {
            shared,
            addr,
            accept: Some(accept),
        })
    }

    /// Where it listens.
    pub fn local_addr(&self) -> SocketAddr {
        self.addr
    }

    /// Whether a robot program is connected.
    pub fn connected(&self) -> bool {
        self.lock().client.is_some()
    }

    /// Sends a command (and remembers it as the robot's current state).
    pub fn command(&self, m: &ServerMsg) {
        let line = to_line(m);
        let mut st = self.lock();
        st.current = Some(line.clone());
        write_or_drop(&mut st, &line);
    }

    /// Sets the token the next robot program must send (off loopback a token is required, so
    /// `None` is ignored there).
    pub fn set_token(&self, token: Option<String>) {
        if token.is_none() && !self.addr.ip().is_loopback() {
            return;
        }
        *self
            .shared
            .token
            .lock()
            .unwrap_or_else(PoisonError::into_inner) = token;
    }

    /// Sends a tick for the tracking frame at `t`.
    pub fn tick(&self, t: f64) {
        let line = to_line(&Tick { t });
        write_or_drop(&mut self.lock(), &line);
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, State> {
        self.shared
            .state
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
    }
}

impl Drop for RobotSink {
    fn drop(&mut self) {
        self.shared.stop.store(true, Ordering::SeqCst);
        if let Some(h) = self.accept.take() {
            let _ = h.join();
        }
        let mut st = self.lock();
        if let Some(c) = st.client.take() {
            let _ = c.shutdown(std::net::Shutdown::Both);
        }
    }
}

/// Writes to the client; a client that cannot take the line in time is dropped.
fn write_or_drop(st: &mut State, line: &str) {
    if let Some(c) = &mut st.client {
        if c.write_all(line.as_bytes()).is_err() {
            if let Some(c) = st.client.take() {
                let _ = c.shutdown(std::net::Shutdown::Both);
            }
        }
    }
}

fn accept_loop(listener: &TcpListener, sh: &Arc<Shared>) {
    while !sh.stop.load(Ordering::SeqCst) {
        let stream = match listener.accept() {
            Ok((s, _)) => s,
            Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => {
                std::thread::sleep(Duration::from_millis(10));
                continue;
            }
            Err(_) => {
                std::thread::sleep(Duration::from_millis(50));
                continue;
            }
        };
        let _ = stream.set_nonblocking(false);
        let _ = stream.set_nodelay(true);
        let _ = stream.set_write_timeout(Some(WRITE_TIMEOUT));
        if lock(&sh.state).client.is_some() {
            refuse(stream, BUSY);
            continue;
        }
        let token = lock(&sh.token).clone();
        let Some(token) = token else {
            admit(sh, stream);
            continue;
        };
        // Each token is read on a thread of its own, so a peer that says nothing delays no
        // one; at most MAX_HANDSHAKES wait at once.
        if sh.handshakes.fetch_add(1, Ordering::SeqCst) >= MAX_HANDSHAKES {
            sh.handshakes.fetch_sub(1, Ordering::SeqCst);
            refuse(stream, "too many robot programs connecting at once");
            continue;
        }
        let sh = Arc::clone(sh);
        let spawned = std::thread::Builder::new()
            .name("robot-sink-hello".into())
            .spawn(move || {
                if token_ok(&stream, &token) {
                    admit(&sh, stream);
                } else {
                    refuse(stream, "missing or wrong token");
                }
                sh.handshakes.fetch_sub(1, Ordering::SeqCst);
            });
        if spawned.is_err() {
            // Out of threads: the connection was dropped with the closure.
            continue;
        }
    }
}

const BUSY: &str = "busy: another robot program is connected to this sink";

fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(PoisonError::into_inner)
}

/// Makes `stream` the sink's robot program (if none is), sending it the current state first.
fn admit(sh: &Shared, mut stream: TcpStream) {
    let mut st = lock(&sh.state);
    if st.client.is_some() {
        drop(st);
        refuse(stream, BUSY);
        return;
    }
    let first = st.current.clone().unwrap_or_else(stop_line);
    if stream.write_all(first.as_bytes()).is_ok() {
        st.client = Some(stream);
    }
}

fn refuse(mut stream: TcpStream, reason: &str) {
    let _ = stream.write_all(
        to_line(&ServerMsg::Error {
            reason: reason.into(),
        })
        .as_bytes(),
    );
    let _ = stream.shutdown(std::net::Shutdown::Both);
}

/// Reads `{"type":"robot","token":"..."}` within the handshake time.
fn token_ok(stream: &TcpStream, token: &str) -> bool {
    #[derive(serde::Deserialize)]
    #[serde(deny_unknown_fields)]
    struct Hello {
        #[serde(rename = "type")]
        kind: String,
        token: String,
    }
    let Ok(read) = stream.try_clone() else {
        return false;
    };
    let _ = read.set_read_timeout(Some(Duration::from_millis(100)));
    let mut reader = LineReader::new(read, 4096);
    let deadline = Instant::now() + HANDSHAKE;
    while Instant::now() < deadline {
        match reader.next() {
            Ok(Line::Text(l)) => {
                return serde_json::from_str::<Hello>(l.trim())
                    .is_ok_and(|h| h.kind == "robot" && crate::server::same_token(&h.token, token))
            }
            Ok(Line::Partial | Line::Timeout) => {}
            _ => return false,
        }
    }
    false
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::io::{BufRead, BufReader};

    fn read_line(r: &mut BufReader<TcpStream>) -> String {
        let mut l = String::new();
        r.read_line(&mut l).expect("a line");
        l
    }

    fn connect(addr: SocketAddr) -> BufReader<TcpStream> {
        let s = TcpStream::connect(addr).expect("connects");
        s.set_read_timeout(Some(Duration::from_secs(5)))
            .expect("timeout");
        BufReader::new(s)
    }

    fn command(turn: f32) -> ServerMsg {
        ServerMsg::Command {
            t: 1.0,
            seq: Some(1),
            turn,
            stop: false,
            reason: None,
            phase: crate::protocol::Phase::Control,
            released: true,
            active_goal: None,
            goals_reached: 0,
        }
    }

    fn wait_connected(sink: &RobotSink, want: bool) {
        let t0 = Instant::now();
        while sink.connected() != want {
            assert!(t0.elapsed() < Duration::from_secs(5), "never {want}");
            std::thread::sleep(Duration::from_millis(5));
        }
    }

    #[test]
    fn one_robot_program_gets_the_current_state_then_commands_and_ticks() {
        let sink = RobotSink::start(TcpListener::bind("127.0.0.1:0").expect("binds"), None)
            .expect("starts");
        let mut a = connect(sink.local_addr());
        // Nothing commanded yet: a stop first.
        assert!(read_line(&mut a).contains(r#""stop":true"#));
        wait_connected(&sink, true);
        sink.command(&command(0.25));
        sink.tick(1.04);
        assert!(read_line(&mut a).contains(r#""turn":0.25"#));
        assert_eq!(read_line(&mut a), "{\"type\":\"tick\",\"t\":1.04}\n");
        // A second program is told busy.
        let mut b = connect(sink.local_addr());
        assert!(read_line(&mut b).contains("busy"));
        // The first leaves; a reconnecting one gets the last command first.
        drop(a);
        sink.tick(1.08); // the write that finds the peer gone
        sink.tick(1.12);
        wait_connected(&sink, false);
        let mut c = connect(sink.local_addr());
        assert!(read_line(&mut c).contains(r#""turn":0.25"#));
    }

    #[test]
    fn off_loopback_needs_a_token_and_a_wrong_one_is_refused() {
        let any = TcpListener::bind("0.0.0.0:0").expect("binds");
        assert!(matches!(
            RobotSink::start(any, None),
            Err(crate::LiveError::Unsafe { .. })
        ));
        let sink = RobotSink::start(
            TcpListener::bind("127.0.0.1:0").expect("binds"),
            Some("s3cret".into()),
        )
        .expect("starts");
        let mut wrong = connect(sink.local_addr());
        wrong
            .get_mut()
            .write_all(b"{\"type\":\"robot\",\"token\":\"guess\"}\n")
            .expect("writes");
        assert!(read_line(&mut wrong).contains("wrong token"));
        // A peer that connects and says nothing delays no one.
        let _silent = connect(sink.local_addr());
        let asked = Instant::now();
        let mut right = connect(sink.local_addr());
        right
            .get_mut()
            .write_all(b"{\"type\":\"robot\",\"token\":\"s3cret\"}\n")
            .expect("writes");
        let first = read_line(&mut right);
        assert!(first.contains(r#""stop":true"#), "{first}");
        assert!(
            asked.elapsed() < Duration::from_secs(2),
            "{:?}",
            asked.elapsed()
        );
        // A new token applies to the next program.
        sink.set_token(Some("n3w".into()));
        drop(right);
        sink.tick(2.0);
        sink.tick(2.04);
        wait_connected(&sink, false);
        let mut old = connect(sink.local_addr());
        old.get_mut()
            .write_all(b"{\"type\":\"robot\",\"token\":\"s3cret\"}\n")
            .expect("writes");
        assert!(read_line(&mut old).contains("wrong token"));
    }
}
