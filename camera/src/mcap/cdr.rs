//! ROS 2 CDR (OMG XCDR1 and plain XCDR2) reading and writing of the few `sensor_msgs` types a
//! replay needs. Hand-written: three message layouts do not justify a serialisation framework,
//! and reading borrows from the record so no frame is copied twice.

/// A malformed message: what was being read and at which byte of the payload.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("CDR: {what} at byte {at}: {message}")]
pub struct CdrError {
    pub what: &'static str,
    pub at: usize,
    pub message: String,
}

/// A cursor over one CDR payload (after its 4-byte encapsulation header).
pub struct CdrReader<'a> {
    body: &'a [u8],
    pos: usize,
    little_endian: bool,
    /// XCDR1 aligns 8-byte values to 8, XCDR2 to 4.
    max_align: usize,
}

impl<'a> CdrReader<'a> {
    /// Reads the encapsulation header: CDR_BE/CDR_LE (ROS 2's default) or PLAIN_CDR2.
    pub fn new(payload: &'a [u8]) -> Result<Self, CdrError> {
        if payload.len() < 4 {
            return Err(err(
                "encapsulation header",
                0,
                "payload shorter than 4 bytes",
            ));
        }
        let (little_endian, max_align) = match (payload[0], payload[1]) {
            (0, 0) => (false, 8),
            (0, 1) => (true, 8),
            (0, 6) => (false, 4),
            (0, 7) => (true, 4),
            (a, b) => {
                return Err(err(
                    "encapsulation header",
                    0,
                    format!("representation {a:#04x}{b:02x} is not plain CDR (parameter lists are not supported)"),
                ))
            }
        };
        Ok(CdrReader {
            body: &payload[4..],
            pos: 0,
            little_endian,
            max_align,
        })
    }

    fn align(&mut self, n: usize) {
        let n = n.min(self.max_align);
        self.pos = self.pos.div_ceil(n) * n;
    }

    fn take(&mut self, n: usize, what: &'static str) -> Result<&'a [u8], CdrError> {
        let end = self.pos.checked_add(n).filter(|&e| e <= self.body.len());
        let Some(end) = end else {
            return Err(err(
                what,
                self.pos + 4,
                format!(
                    "needs {n} bytes, {} left (truncated message)",
                    self.body.len().saturating_sub(self.pos)
                ),
            ));
        };
        let s = &self.body[self.pos..end];
        self.pos = end;
        Ok(s)
    }

    pub fn u8(&mut self, what: &'static str) -> Result<u8, CdrError> {
        Ok(self.take(1, what)?[0])
    }

    pub fn u32(&mut self, what: &'static str) -> Result<u32, CdrError> {
        self.align(4);
        let b: [u8; 4] = self.take(4, what)?.try_into().unwrap_or_default();
        Ok(if self.little_endian {
            u32::from_le_bytes(b)
        } else {
            u32::from_be_bytes(b)
        })
    }

    pub fn i32(&mut self, what: &'static str) -> Result<i32, CdrError> {
        Ok(self.u32(what)? as i32)
    }

    pub fn f64(&mut self, what: &'static str) -> Result<f64, CdrError> {
        self.align(8);
        let b: [u8; 8] = self.take(8, what)?.try_into().unwrap_or_default();
        Ok(if self.little_endian {
            f64::from_le_bytes(b)
        } else {
            f64::from_be_bytes(b)
        })
    }

    /// A string: length with its NUL terminator, bytes, NUL.
    pub fn string(&mut self, what: &'static str) -> Result<&'a str, CdrError> {
        let at = self.pos + 4;
        let n = self.u32(what)? as usize;
        let bytes = self.take(n, what)?;
        let bytes = bytes.strip_suffix(&[0]).unwrap_or(bytes);
        std::str::from_utf8(bytes).map_err(|_| err(what, at, "string is not UTF-8"))
    }

    /// A `uint8[]` sequence, borrowed.
    pub fn bytes(&mut self, what: &'static str) -> Result<&'a [u8], CdrError> {
        let n = self.u32(what)? as usize;
        self.take(n, what)
    }

    /// A `float64[]` sequence.
    pub fn f64_seq(&mut self, what: &'static str, out: &mut Vec<f64>) -> Result<(), CdrError> {
        let n = self.u32(what)? as usize;
        if n > self.body.len() / 8 + 1 {
            return Err(err(what, self.pos + 4, format!("claims {n} values")));
        }
        out.clear();
        for _ in 0..n {
            out.push(self.f64(what)?);
        }
        Ok(())
    }

    pub fn f64_array<const N: usize>(&mut self, what: &'static str) -> Result<[f64; N], CdrError> {
        let mut a = [0.0; N];
        for v in &mut a {
            *v = self.f64(what)?;
        }
        Ok(a)
    }

    /// `std_msgs/Header`: the stamp in seconds, and the frame id.
    pub fn header(&mut self) -> Result<(f64, &'a str), CdrError> {
        let sec = self.i32("header.stamp.sec")?;
        let nanosec = self.u32("header.stamp.nanosec")?;
        let frame_id = self.string("header.frame_id")?;
        Ok((sec as f64 + nanosec as f64 * 1e-9, frame_id))
    }
}

fn err(what: &'static str, at: usize, message: impl Into<String>) -> CdrError {
    CdrError {
        what,
        at,
        message: message.into(),
    }
}

/// Little-endian XCDR1 writer (what ROS 2's default middleware writes).
pub struct CdrWriter {
    buf: Vec<u8>,
}

impl Default for CdrWriter {
    fn default() -> Self {
        Self::new()
    }
}

impl CdrWriter {
    pub fn new() -> Self {
        CdrWriter {
            buf: vec![0, 1, 0, 0],
        }
    }

    /// Starts a new message in the same buffer.
    pub fn reset(&mut self) {
        self.buf.clear();
        self.buf.extend_from_slice(&[0, 1, 0, 0]);
    }

    fn align(&mut self, n: usize) {
        while !(self.buf.len() - 4).is_multiple_of(n) {
            self.buf.push(0);
        }
    }

    pub fn u8(&mut self, v: u8) {
        self.buf.push(v);
    }

    pub fn u32(&mut self, v: u32) {
        self.align(4);
        self.buf.extend_from_slice(&v.to_le_bytes());
    }

    pub fn i32(&mut self, v: i32) {
        self.u32(v as u32);
    }

    pub fn f64(&mut self, v: f64) {
        self.align(8);
        self.buf.extend_from_slice(&v.to_le_bytes());
    }

    pub fn string(&mut self, s: &str) {
        self.u32(s.len() as u32 + 1);
        self.buf.extend_from_slice(s.as_bytes());
        self.buf.push(0);
    }

    pub fn bytes(&mut self, b: &[u8]) {
        self.u32(b.len() as u32);
        self.buf.extend_from_slice(b);
    }

    /// `std_msgs/Header` with the stamp split into seconds and nanoseconds.
    pub fn header(&mut self, stamp_ns: u64, frame_id: &str) {
        self.i32((stamp_ns / 1_000_000_000) as i32);
        self.u32((stamp_ns % 1_000_000_000) as u32);
        self.string(frame_id);
    }

    pub fn as_bytes(&self) -> &[u8] {
        &self.buf
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_with_alignment() {
        let mut w = CdrWriter::new();
        w.header(1_500_000_000, "cam");
        w.u8(7);
        w.f64(0.25);
        w.string("mono8");
        w.bytes(&[1, 2, 3]);
        let mut r = CdrReader::new(w.as_bytes()).unwrap();
        let (t, id) = r.header().unwrap();
        assert_eq!((t, id), (1.5, "cam"));
        assert_eq!(r.u8("a").unwrap(), 7);
        // The f64 starts on an 8-byte boundary of the body.
        assert_eq!(r.f64("b").unwrap(), 0.25);
        assert_eq!(r.string("c").unwrap(), "mono8");
        assert_eq!(r.bytes("d").unwrap(), &[1, 2, 3]);
        assert!(r.u8("e").is_err());
    }

    #[test]
    fn truncated_and_foreign_payloads_are_errors_not_panics() {
        let mut w = CdrWriter::new();
        w.header(0, "x");
        w.bytes(&[9; 100]);
        let full = w.as_bytes();
        for cut in 0..full.len() {
            let r = CdrReader::new(&full[..cut]);
            if let Ok(mut r) = r {
                let _ = r.header().and_then(|_| r.bytes("data"));
            }
        }
        let mut r = CdrReader::new(&full[..full.len() - 1]).unwrap();
        r.header().unwrap();
        let e = r.bytes("data").unwrap_err();
        assert!(e.to_string().contains("truncated"), "{e}");
        assert!(CdrReader::new(&[0, 3, 0, 0]).is_err());
        // Big-endian CDR reads too.
        let mut r = CdrReader::new(&[0, 0, 0, 0, 0, 0, 0, 5]).unwrap();
        assert_eq!(r.u32("n").unwrap(), 5);
    }
}
