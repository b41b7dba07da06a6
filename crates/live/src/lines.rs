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

/// Longest line a client of a bridge (the virtual lab with `--connect`, `live replay`) reads
/// from it: the bridge's own messages are under 1 kB, and this is the bridge's own limit on
/// what it reads (`max_message_bytes`' default), so a hostile or broken peer cannot grow a
/// client's memory with a line that never ends.
pub const MAX_BRIDGE_LINE_BYTES: usize = 65_536;

/// One line (without its newline) of at most `max` bytes, `None` once the peer has closed.
/// A longer line, or one that is not UTF-8, is an error, read no further than `max + 1` bytes.
pub fn read_line_at_most<R: BufRead>(r: &mut R, max: usize) -> std::io::Result<Option<String>> {
    use std::io::Read;
    let mut buf = Vec::new();
    let n = r
        .by_ref()
        .take(max as u64 + 1)
        .read_until(b'\n', &mut buf)?;
    if n == 0 {
        return Ok(None);
    }
    if buf.last() == Some(&b'\n') {
        buf.pop();
    } else if buf.len() > max {
        return Err(std::io::Error::new(
            ErrorKind::InvalidData,
            format!("a line longer than {max} bytes (reading stopped there)"),
        ));
    }
    String::from_utf8(buf)
        .map(Some)
        .map_err(|_| std::io::Error::new(ErrorKind::InvalidData, "a line that is not UTF-8 text"))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lines_are_read_up_to_their_limit_and_no_further() {
        let mut r = std::io::Cursor::new(b"abc\ndefg\nhi".to_vec());
        assert_eq!(
            read_line_at_most(&mut r, 4).unwrap().as_deref(),
            Some("abc")
        );
        // Exactly the limit, newline not counted.
        assert_eq!(
            read_line_at_most(&mut r, 4).unwrap().as_deref(),
            Some("defg")
        );
        // A last line without a newline.
        assert_eq!(read_line_at_most(&mut r, 4).unwrap().as_deref(), Some("hi"));
        assert_eq!(read_line_at_most(&mut r, 4).unwrap(), None);

        let mut long = std::io::Cursor::new(b"abcdef\n".to_vec());
        let err = read_line_at_most(&mut long, 4).unwrap_err().to_string();
        assert!(err.contains("longer than 4 bytes"), "{err}");
        assert_eq!(long.position(), 5, "read no further than the limit + 1");

        let mut binary = std::io::Cursor::new(vec![0xff, b'\n']);
        assert!(read_line_at_most(&mut binary, 4).is_err());
    }

    #[test]
    fn a_line_that_never_ends_is_refused() {
        let mut endless = std::io::BufReader::new(std::io::repeat(b'x'));
        let err = read_line_at_most(&mut endless, MAX_BRIDGE_LINE_BYTES).unwrap_err();
        assert_eq!(err.kind(), ErrorKind::InvalidData);
    }
}
