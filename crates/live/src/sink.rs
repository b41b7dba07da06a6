//! The robot sink: where the lab's robot program reads fishprobe's commands when the tracker
//! (BioTracker v4) is the one talking to fishprobe.
//!
//! fishprobe listens (loopback by default) and streams newline-delimited JSON to one robot
//! program: the live protocol's `command` messages (`docs/live-protocol.md`) and, on every
//! tracking frame, a `tick` (`{"type":"tick","t":12.04}`), so the robot side can stop on its
//! own when fishprobe falls silent (the documented watchdog: stop after [`WATCHDOG_S`]
//! without a line).
//!
//! The program answers each tick it has read with `{"type":"ack","t":12.04}`. A program that
//! leaves a tick unanswered for [`ACK_WITHIN_S`] is not reading: it is dropped (the connection
//! is reset) by the sink, not left to fill kernel buffers with commands it would read late. So
//! what a stalled program can still find in its socket is at most that long's lines. A program
//! that closes its end is noticed at once, so the next one is admitted without waiting for a
//! failed write.
//!
//! A second program that connects while one is served is told `busy` and closed. A program
//! that connects (or reconnects) first gets the robot's current state: the last command, or a
//! stop when there was none. Off loopback the program must first send
//! `{"type":"robot","token":"..."}`; at most [`MAX_HANDSHAKES`] may be doing so at once, and a
//! further one pushes out the one that has waited longest.

use crate::lines::{Line, LineReader};
use crate::protocol::{to_line, ServerMsg};
use crate::track::Command;
use std::collections::VecDeque;
use std::io::Write;
use std::net::{SocketAddr, TcpListener, TcpStream};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex, PoisonError};
use std::time::{Duration, Instant};

/// A robot program should stop its robot when no line came for this long (s): two ticks at
/// the slowest tracking rate BioTracker runs at (4 Hz) and a dozen at the lab's 25 Hz.
pub const WATCHDOG_S: f64 = 0.5;

/// A robot program must acknowledge a tick within this long (s) of its sending, or it is
/// dropped (choice: 0.2 s, five frames at 25 Hz: a program that reads keeps up with ease on
/// a lab network, and what a stalled one finds later in its socket is at most this long's
/// lines).
pub const ACK_WITHIN_S: f64 = 0.2;

/// How long one write to the robot program may block (its socket's send buffer full) before
/// the program is dropped. Acknowledged programs never get near it; it bounds how long the
/// tracking loop can wait on a program.
const WRITE_TIMEOUT: Duration = Duration::from_millis(50);

/// How long a program off loopback has to send its token.
const HANDSHAKE: Duration = Duration::from_secs(5);

/// Robot programs that may be sending their token at once; one more pushes out the one that
/// has waited longest, so idle connections cannot hold the sink.
pub const MAX_HANDSHAKES: usize = 8;

/// The longest line a robot program may send (an ack or the token message).
const MAX_PROGRAM_LINE: usize = 4096;

/// Ticks awaiting acknowledgement, at most: far more than [`ACK_WITHIN_S`] holds at any
/// tracking rate BioTracker runs at, so reaching it means the program is not reading.
const MAX_UNACKED: usize = 1024;

/// One tick line.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(tag = "type", rename = "tick")]
pub struct Tick {
    /// The tracking frame's time (s).
    pub t: f64,
}

/// The robot program's answer to a tick.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(tag = "type", rename = "ack")]
pub struct Ack {
    /// The acknowledged tick's `t`, as received.
    pub t: f64,
}

struct Client {
    stream: TcpStream,
    /// Which connection this is (a reader thread only clears its own).
    id: u64,
    /// Ticks sent and not yet acknowledged, oldest first: `t` and when it was sent.
    unacked: VecDeque<(f64, Instant)>,
}

#[derive(Default)]
struct State {
    client: Option<Client>,
    /// The last command sent, as its line: what a reconnecting program gets first.
    current: Option<String>,
    /// Why programs were dropped since the owner last asked.
    dropped: Vec<String>,
}

impl State {
    /// Drops the program (resetting the connection, so nothing more is queued for it).
    fn drop_client(&mut self, why: String) {
        if let Some(c) = self.client.take() {
            reset(&c.stream);
            self.dropped.push(why);
        }
    }

    /// Drops the program if it left a tick unacknowledged for too long.
    fn check_acks(&mut self, now: Instant) {
        let late = self.client.as_ref().and_then(|c| {
            let &(t, sent) = c.unacked.front()?;
            let waited = now.saturating_duration_since(sent).as_secs_f64();
            (waited > ACK_WITHIN_S || c.unacked.len() >= MAX_UNACKED).then_some((t, waited))
        });
        if let Some((t, waited)) = late {
            self.drop_client(format!(
                "the robot program did not acknowledge the tick at t = {t} s within \
                 {ACK_WITHIN_S} s ({waited:.2} s): it is not reading, so it was disconnected"
            ));
        }
    }
}

struct Shared {
    state: Mutex<State>,
    stop: AtomicBool,
    token: Mutex<Option<String>>,
    /// Handshakes in progress (off loopback), oldest first: id and a handle to close it.
    handshakes: Mutex<VecDeque<(u64, TcpStream)>>,
    next_id: AtomicU64,
}

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
    to_line(&ServerMsg::Command(Command::stop_outside_trial(
        0.0,
        "no command yet",
        0,
    )))
}

/// Closes a connection with a reset: what the kernel still holds for it is discarded on
/// this side, and the peer learns at once.
fn reset(s: &TcpStream) {
    let _ = socket2::SockRef::from(s).set_linger(Some(Duration::ZERO));
    let _ = s.shutdown(std::net::Shutdown::Both);
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
            handshakes: Mutex::new(VecDeque::new()),
            next_id: AtomicU64::new(1),
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

    /// Whether a robot program is connected (and keeping up with its acknowledgements).
    pub fn connected(&self) -> bool {
        let mut st = self.lock();
        st.check_acks(Instant::now());
        st.client.is_some()
    }

    /// Why robot programs were dropped since the last call (for the log).
    pub fn take_dropped(&self) -> Vec<String> {
        std::mem::take(&mut self.lock().dropped)
    }

    /// Sends a command (and remembers it as the robot's current state).
    pub fn command(&self, c: &Command) {
        let line = to_line(&ServerMsg::Command(c.clone()));
        let mut st = self.lock();
        st.current = Some(line.clone());
        write_or_drop(&mut st, &line, None);
    }

    /// Sets the token the next robot program must send (off loopback a token is required, so
    /// `None` is ignored there).
    pub fn set_token(&self, token: Option<String>) {
        if token.is_none() && !self.addr.ip().is_loopback() {
            return;
        }
        *lock(&self.shared.token) = token;
    }

    /// Sends a tick for the tracking frame at `t`; the program must acknowledge it within
    /// [`ACK_WITHIN_S`].
    pub fn tick(&self, t: f64) {
        let line = to_line(&Tick { t });
        write_or_drop(&mut self.lock(), &line, Some(t));
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, State> {
        lock(&self.shared.state)
    }
}

impl Drop for RobotSink {
    fn drop(&mut self) {
        self.shared.stop.store(true, Ordering::SeqCst);
        if let Some(h) = self.accept.take() {
            let _ = h.join();
        }
        for (_, s) in lock(&self.shared.handshakes).drain(..) {
            let _ = s.shutdown(std::net::Shutdown::Both);
        }
        let mut st = self.lock();
        if let Some(c) = st.client.take() {
            let _ = c.stream.shutdown(std::net::Shutdown::Both);
        }
    }
}

/// Writes to the client (first dropping it if it fell behind with its acknowledgements); a
/// client that cannot take the line in time is dropped. A tick's `t` is remembered until the
/// program acknowledges it.
fn write_or_drop(st: &mut State, line: &str, tick: Option<f64>) {
    let now = Instant::now();
    st.check_acks(now);
    let Some(c) = &mut st.client else {
        return;
    };
    if let Err(e) = c.stream.write_all(line.as_bytes()) {
        st.drop_client(format!(
            "a write to the robot program failed ({e}), so it was disconnected"
        ));
        return;
    }
    if let Some(t) = tick {
        c.unacked.push_back((t, now));
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
                // Out of descriptors or similar: wait rather than spin.
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
            admit(sh, stream, None);
            continue;
        };
        // Each token is read on a thread of its own, so a peer that says nothing delays no
        // one; with MAX_HANDSHAKES waiting, the one that has waited longest is pushed out.
        let id = sh.next_id.fetch_add(1, Ordering::SeqCst);
        let Ok(handle) = stream.try_clone() else {
            continue;
        };
        {
            let mut hs = lock(&sh.handshakes);
            while hs.len() >= MAX_HANDSHAKES {
                if let Some((_, oldest)) = hs.pop_front() {
                    let _ = oldest.shutdown(std::net::Shutdown::Both);
                }
            }
            hs.push_back((id, handle));
        }
        let sh2 = Arc::clone(sh);
        let spawned = std::thread::Builder::new()
            .name("robot-sink-hello".into())
            .spawn(move || {
                let reader = token_ok(&stream, &token);
                lock(&sh2.handshakes).retain(|(i, _)| *i != id);
                match reader {
                    Some(reader) => admit(&sh2, stream, Some(reader)),
                    None => refuse(stream, "missing or wrong token"),
                }
            });
        if spawned.is_err() {
            // Out of threads: the connection was dropped with the closure.
            lock(&sh.handshakes).retain(|(i, _)| *i != id);
        }
    }
}

const BUSY: &str = "busy: another robot program is connected to this sink";

fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(PoisonError::into_inner)
}

/// Makes `stream` the sink's robot program (if none is), sending it the current state first,
/// and starts reading its acknowledgements (`reader`: what the handshake already read).
fn admit(sh: &Arc<Shared>, mut stream: TcpStream, reader: Option<LineReader>) {
    let reader = match reader {
        Some(r) => r,
        None => match stream.try_clone() {
            Ok(r) => LineReader::new(r, MAX_PROGRAM_LINE),
            Err(_) => return,
        },
    };
    let id = sh.next_id.fetch_add(1, Ordering::SeqCst);
    let mut st = lock(&sh.state);
    if st.client.is_some() {
        drop(st);
        refuse(stream, BUSY);
        return;
    }
    let first = st.current.clone().unwrap_or_else(stop_line);
    if stream.write_all(first.as_bytes()).is_err() {
        return;
    }
    let _ = reader
        .get_ref()
        .set_read_timeout(Some(Duration::from_millis(20)));
    st.client = Some(Client {
        stream,
        id,
        unacked: VecDeque::new(),
    });
    drop(st);
    let sh2 = Arc::clone(sh);
    let spawned = std::thread::Builder::new()
        .name("robot-sink-acks".into())
        .spawn(move || read_acks(&sh2, reader, id));
    if spawned.is_err() {
        // Out of threads: a program whose acknowledgements cannot be read cannot be served.
        lock(&sh.state).drop_client("no thread to read the robot program's acks".into());
    }
}

/// Reads the program's acknowledgements until it leaves or is dropped; notices a program
/// that closes at once.
fn read_acks(sh: &Shared, mut reader: LineReader, id: u64) {
    let ours = |st: &State| st.client.as_ref().is_some_and(|c| c.id == id);
    loop {
        if sh.stop.load(Ordering::SeqCst) {
            return;
        }
        let line = reader.next();
        let mut st = lock(&sh.state);
        if !ours(&st) {
            return;
        }
        match line {
            Ok(Line::Text(l)) => match serde_json::from_str::<Ack>(l.trim()) {
                Ok(a) => {
                    if let Some(c) = st.client.as_mut() {
                        // Within a rounding of the JSON round trip.
                        let same = |t: f64| (t - a.t).abs() <= 1e-9 * t.abs().max(1.0);
                        if let Some(k) = c.unacked.iter().position(|&(t, _)| same(t)) {
                            c.unacked.drain(..=k);
                        }
                    }
                }
                Err(e) => {
                    st.drop_client(format!(
                        "the robot program sent a line that is not an ack ({e}), so it was \
                         disconnected"
                    ));
                    return;
                }
            },
            Ok(Line::Partial | Line::Timeout) => {}
            Ok(Line::TooLong(n)) => {
                st.drop_client(format!(
                    "the robot program sent a {n}-byte line (at most {MAX_PROGRAM_LINE}), so it \
                     was disconnected"
                ));
                return;
            }
            Ok(Line::Binary) => {
                st.drop_client("the robot program sent a line that is not UTF-8".into());
                return;
            }
            Ok(Line::Closed) | Err(_) => {
                if let Some(c) = st.client.take() {
                    let _ = c.stream.shutdown(std::net::Shutdown::Both);
                    st.dropped
                        .push("the robot program closed its connection".into());
                }
                return;
            }
        }
        st.check_acks(Instant::now());
        if !ours(&st) {
            return;
        }
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

/// Reads `{"type":"robot","token":"..."}` within the handshake time; the reader, to go on
/// reading the program's acknowledgements, when it was right.
fn token_ok(stream: &TcpStream, token: &str) -> Option<LineReader> {
    #[derive(serde::Deserialize)]
    #[serde(deny_unknown_fields)]
    struct Hello {
        #[serde(rename = "type")]
        kind: String,
        token: String,
    }
    let read = stream.try_clone().ok()?;
    let _ = read.set_read_timeout(Some(Duration::from_millis(100)));
    let mut reader = LineReader::new(read, MAX_PROGRAM_LINE);
    let deadline = Instant::now() + HANDSHAKE;
    while Instant::now() < deadline {
        match reader.next() {
            Ok(Line::Text(l)) => {
                return serde_json::from_str::<Hello>(l.trim())
                    .is_ok_and(|h| h.kind == "robot" && crate::server::same_token(&h.token, token))
                    .then_some(reader)
            }
            Ok(Line::Partial | Line::Timeout) => {}
            _ => return None,
        }
    }
    None
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

    /// Reads a line and acknowledges it when it is a tick.
    fn read_and_ack(r: &mut BufReader<TcpStream>) -> String {
        let l = read_line(r);
        if let Ok(t) = serde_json::from_str::<Tick>(l.trim()) {
            let ack = serde_json::to_string(&Ack { t: t.t }).expect("ack") + "\n";
            r.get_mut().write_all(ack.as_bytes()).expect("acks");
        }
        l
    }

    fn command(turn: f32) -> Command {
        Command {
            t: 1.0,
            seq: Some(1),
            turn,
            stop: false,
            reason: None,
            phase: crate::track::Phase::Control,
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

    fn loopback_sink() -> RobotSink {
        RobotSink::start(TcpListener::bind("127.0.0.1:0").expect("binds"), None).expect("starts")
    }

    #[test]
    fn one_robot_program_gets_the_current_state_then_commands_and_ticks() {
        let sink = loopback_sink();
        let mut a = connect(sink.local_addr());
        // Nothing commanded yet: a stop first.
        assert!(read_line(&mut a).contains(r#""stop":true"#));
        wait_connected(&sink, true);
        sink.command(&command(0.25));
        sink.tick(1.04);
        assert!(read_and_ack(&mut a).contains(r#""turn":0.25"#));
        assert_eq!(read_and_ack(&mut a), "{\"type\":\"tick\",\"t\":1.04}\n");
        // A second program is told busy.
        let mut b = connect(sink.local_addr());
        assert!(read_line(&mut b).contains("busy"));
        // The first leaves: noticed without a write, and a reconnecting one gets the last
        // command first.
        drop(a);
        wait_connected(&sink, false);
        assert_eq!(
            sink.take_dropped(),
            vec!["the robot program closed its connection".to_string()]
        );
        let mut c = connect(sink.local_addr());
        assert!(read_line(&mut c).contains(r#""turn":0.25"#));
    }

    #[test]
    fn a_program_that_acknowledges_stays_and_one_that_does_not_read_is_dropped_in_time() {
        let sink = loopback_sink();
        let mut a = connect(sink.local_addr());
        read_line(&mut a);
        wait_connected(&sink, true);
        // Two seconds at 25 Hz, each tick acknowledged: never dropped.
        for k in 0..50 {
            sink.tick(f64::from(k) * 0.04);
            sink.command(&command(0.1));
            read_and_ack(&mut a);
            read_and_ack(&mut a);
            std::thread::sleep(Duration::from_millis(40));
        }
        assert!(sink.connected(), "{:?}", sink.take_dropped());
        drop(a);
        wait_connected(&sink, false);
        sink.take_dropped();

        // A program with a tiny receive buffer that never reads.
        let s = socket2::Socket::new(socket2::Domain::IPV4, socket2::Type::STREAM, None)
            .expect("socket");
        s.set_recv_buffer_size(1024).expect("small buffer");
        s.connect(&sink.local_addr().into()).expect("connects");
        let stalled: TcpStream = s.into();
        wait_connected(&sink, true);
        let t0 = Instant::now();
        let mut gone = None;
        for k in 0..100 {
            sink.tick(f64::from(k) * 0.04);
            sink.command(&command(0.2));
            if gone.is_none() && !sink.connected() {
                gone = Some(t0.elapsed());
            }
            std::thread::sleep(Duration::from_millis(40));
        }
        let gone = gone.expect("the stalled program was never dropped");
        assert!(
            gone.as_secs_f64() < ACK_WITHIN_S + 0.1,
            "dropped after {gone:?}"
        );
        let why = sink.take_dropped();
        assert!(why[0].contains("did not acknowledge"), "{why:?}");
        // What the program finds when it reads at last: the state it was admitted with and at
        // most ACK_WITHIN_S of lines, then the end; never the 4 s of commands since.
        stalled
            .set_read_timeout(Some(Duration::from_secs(2)))
            .expect("timeout");
        let mut r = BufReader::new(stalled);
        let mut lines = 0;
        let mut l = String::new();
        while matches!(r.read_line(&mut l), Ok(n) if n > 0) {
            lines += 1;
            l.clear();
        }
        let per_frame = 2.0;
        let most = 1.0 + per_frame * ((ACK_WITHIN_S + 0.1) / 0.04).ceil();
        assert!(f64::from(lines) <= most, "{lines} lines delivered late");
        // The sink is free for the next program.
        let mut next = connect(sink.local_addr());
        assert!(read_line(&mut next).contains(r#""turn":0.2"#));
    }

    #[test]
    fn a_program_that_says_something_else_is_dropped_with_the_reason() {
        let sink = loopback_sink();
        let mut a = connect(sink.local_addr());
        read_line(&mut a);
        wait_connected(&sink, true);
        a.get_mut().write_all(b"hello\n").expect("writes");
        wait_connected(&sink, false);
        assert!(sink.take_dropped()[0].contains("not an ack"));
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
        // Peers that connect and say nothing, more of them than there are handshake slots,
        // delay no one: the longest-waiting is pushed out.
        let silent: Vec<_> = (0..MAX_HANDSHAKES + 2)
            .map(|_| connect(sink.local_addr()))
            .collect();
        std::thread::sleep(Duration::from_millis(100));
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
        drop(silent);
        // Acknowledgements are read after the token too.
        sink.tick(2.0);
        assert!(read_and_ack(&mut right).contains("tick"));
        std::thread::sleep(Duration::from_millis(300));
        assert!(sink.connected(), "{:?}", sink.take_dropped());
        // A new token applies to the next program.
        sink.set_token(Some("n3w".into()));
        drop(right);
        wait_connected(&sink, false);
        let mut old = connect(sink.local_addr());
        old.get_mut()
            .write_all(b"{\"type\":\"robot\",\"token\":\"s3cret\"}\n")
            .expect("writes");
        assert!(read_line(&mut old).contains("wrong token"));
    }
}
