//! Frame timestamps from kernel buffer times: the driver's monotonic capture time (when it says
//! so) in seconds, else the host's monotonic clock at dequeue; made strictly increasing, with
//! gaps in the driver's sequence numbers counted as frames the driver dropped.

/// Metadata of one dequeued device buffer.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct BufferMeta {
    /// Driver frame counter (wraps at 2^32).
    pub sequence: u32,
    /// Capture time, seconds and microseconds (`struct timeval`).
    pub sec: i64,
    pub usec: i64,
    /// True when the driver's timestamp is from CLOCK_MONOTONIC (V4L2_BUF_FLAG_TIMESTAMP_MONOTONIC).
    pub monotonic: bool,
    /// Bytes of image data in the buffer.
    pub bytes_used: usize,
    /// The driver flagged the buffer as corrupt (V4L2_BUF_FLAG_ERROR).
    pub error: bool,
}

/// Host CLOCK_MONOTONIC in seconds (the clock V4L2 stamps buffers with).
pub fn monotonic_now() -> f64 {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: clock_gettime writes into the timespec we own; CLOCK_MONOTONIC always exists on Linux.
    unsafe { libc::clock_gettime(libc::CLOCK_MONOTONIC, &mut ts) };
    ts.tv_sec as f64 + ts.tv_nsec as f64 * 1e-9
}

/// How far a driver's monotonic stamp may be from the host's monotonic clock to be trusted.
const TRUSTED_CLOCK_SPAN_S: f64 = 1e5;

/// Turns buffer metadata into frame timestamps and counts what went wrong on the way.
#[derive(Clone, Debug, Default)]
pub struct Timestamper {
    last: Option<f64>,
    last_sequence: Option<u32>,
    /// Frames the driver dropped (gaps in sequence numbers).
    pub driver_drops: u64,
    /// Timestamps that were not after the previous one and were moved 1 us past it.
    pub repaired: u64,
    /// Frames stamped with the host clock because the driver's clock is not monotonic.
    pub host_stamped: u64,
    /// Sum and count of (host now - capture time) for monotonic stamps: the capture-to-dequeue
    /// latency.
    pub age_sum_s: f64,
    pub age_count: u64,
}

impl Timestamper {
    /// Timestamp in seconds of a buffer dequeued at host time `now` (monotonic seconds).
    pub fn stamp(&mut self, meta: &BufferMeta, now: f64) -> f64 {
        if let Some(prev) = self.last_sequence {
            let gap = meta.sequence.wrapping_sub(prev);
            // A jump backwards (stream restart) is not a drop.
            if gap > 1 && gap < u32::MAX / 2 {
                self.driver_drops += (gap - 1) as u64;
            }
        }
        self.last_sequence = Some(meta.sequence);
        let kernel = meta.sec as f64 + meta.usec as f64 * 1e-6;
        // A "monotonic" stamp far from the host's monotonic clock is from another clock (a driver
        // bug, or wall time): not trusted. A fake device replaying faster than real time runs
        // ahead of the host clock, within this margin.
        let mut t = if meta.monotonic && kernel > 0.0 && (kernel - now).abs() < TRUSTED_CLOCK_SPAN_S
        {
            if kernel <= now {
                self.age_sum_s += now - kernel;
                self.age_count += 1;
            }
            kernel
        } else {
            self.host_stamped += 1;
            now
        };
        if let Some(last) = self.last {
            if t <= last {
                t = last + 1e-6;
                self.repaired += 1;
            }
        }
        self.last = Some(t);
        t
    }

    /// Mean capture-to-dequeue latency in milliseconds, when the driver's clock allowed it.
    pub fn mean_age_ms(&self) -> Option<f64> {
        (self.age_count > 0).then(|| self.age_sum_s / self.age_count as f64 * 1e3)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn meta(sequence: u32, t: f64) -> BufferMeta {
        BufferMeta {
            sequence,
            sec: t.floor() as i64,
            usec: ((t - t.floor()) * 1e6).round() as i64,
            monotonic: true,
            bytes_used: 0,
            error: false,
        }
    }

    #[test]
    fn monotonic_kernel_time_is_used_in_seconds() {
        let mut s = Timestamper::default();
        let t = s.stamp(&meta(7, 1234.5), 1234.51);
        assert!((t - 1234.5).abs() < 1e-9);
        assert!((s.mean_age_ms().unwrap() - 10.0).abs() < 1e-3);
    }

    #[test]
    fn sequence_gaps_count_driver_drops() {
        let mut s = Timestamper::default();
        s.stamp(&meta(1, 10.0), 10.0);
        s.stamp(&meta(2, 10.033), 10.04);
        s.stamp(&meta(5, 10.133), 10.14);
        assert_eq!(s.driver_drops, 2);
        // Wrap-around is continuous.
        let mut s = Timestamper::default();
        s.stamp(&meta(u32::MAX, 1.0), 1.0);
        s.stamp(&meta(0, 1.033), 1.04);
        assert_eq!(s.driver_drops, 0);
    }

    #[test]
    fn non_monotonic_or_zero_stamps_fall_back_to_the_host_clock() {
        let mut s = Timestamper::default();
        let mut m = meta(1, 99.0);
        m.monotonic = false;
        assert_eq!(s.stamp(&m, 5.0), 5.0);
        assert_eq!(s.stamp(&meta(2, 0.0), 5.1), 5.1);
        // A kernel time in the future (wrong clock) is not trusted either.
        assert_eq!(s.stamp(&meta(3, 1.7e9), 5.2), 5.2);
        assert_eq!(s.host_stamped, 3);
    }

    #[test]
    fn timestamps_strictly_increase() {
        let mut s = Timestamper::default();
        let a = s.stamp(&meta(1, 10.0), 10.0);
        let b = s.stamp(&meta(2, 10.0), 10.01);
        let c = s.stamp(&meta(3, 9.0), 10.02);
        assert!(a < b && b < c);
        assert_eq!(s.repaired, 2);
    }

    #[test]
    fn host_clock_is_monotonic_seconds() {
        let a = monotonic_now();
        let b = monotonic_now();
        assert!(a > 0.0 && b >= a);
    }
}
