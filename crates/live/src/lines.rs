//! Newline-delimited messages from a socket with a read timeout, bounded in memory.

use std::io::{BufRead, BufReader, ErrorKind};
use std::net::TcpStream;

/// What one read produced.
#[derive(Debug, PartialEq)]
pub(crate) enum Line {
    /// A complete line.
    Text(String),
    /// A line longer than the limit was dropped (its length so far).
    TooLong(usize),
    /// A line that is not UTF-8.
    Binary,
    /// Bytes arrived but no complete line yet (kept for the next read). A peer trickling a
    /// byte at a time gets this on every read, so the caller's clocks (silence, handshake
    /// deadline) keep running: incomplete input is never taken for a sign of life.
    Partial,
    /// Nothing arrived within the read timeout.
    Timeout,
    /// The peer closed.
    Closed,
}

/// Lines of at most `max` bytes. A partial line survives a timeout; an oversized one is
/// discarded up to its newline without being stored.
pub(crate) struct LineReader {
    r: BufReader<TcpStream>,
    buf: Vec<u8>,
    max: usize,
    discarding: Option<usize>,
}

impl LineReader {
    pub(crate) fn new(s: TcpStream, max: usize) -> Self {
        Self {
            r: BufReader::new(s),
            buf: Vec::new(),
            max,
            discarding: None,
        }
    }

    /// The socket (to change its timeout).
    pub(crate) fn get_ref(&self) -> &TcpStream {
        self.r.get_ref()
    }

    /// The next complete line, or what happened instead, after at most one blocking read.
    pub(crate) fn next(&mut self) -> std::io::Result<Line> {
        loop {
            let had_buffered = !self.r.buffer().is_empty();
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
            // The whole buffer was a line's beginning. If it came from the socket just now,
            // report it; if it was left from an earlier read, read on.
            if !had_buffered {
                return Ok(Line::Partial);
            }
        }
    }
}
