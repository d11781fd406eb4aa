//! Pacing: order, real-time release, drop-oldest, panics, stops and interrupts.

mod panic_tests {
    use super::super::*;

    struct Panics(SourceInfo, u32);
    impl FrameSource for Panics {
        fn info(&self) -> &SourceInfo {
            &self.0
        }
        fn next_frame(&mut self, out: &mut Frame) -> Result<FrameStatus, SourceError> {
            self.1 += 1;
            if self.1 == 3 {
                panic!("decoder bug");
            }
            out.index = self.1 as u64;
            Ok(FrameStatus::Ready)
        }
    }

    #[test]
    fn a_panicking_source_is_an_error_not_an_end() {
        let info = SourceInfo {
            name: "p".into(),
            width: 4,
            height: 4,
            fps: 30.0,
            has_color: false,
            len: None,
        };
        let mut p = PacedSource::spawn(Panics(info, 0), Pacing::AsFastAsPossible).unwrap();
        let mut f = Frame::new(4, 4);
        assert_eq!(p.next_frame(&mut f).unwrap(), FrameStatus::Ready);
        assert_eq!(p.next_frame(&mut f).unwrap(), FrameStatus::Ready);
        let e = p.next_frame(&mut f).unwrap_err();
        assert!(e.to_string().contains("decoder bug"), "{e}");
        assert_eq!(p.next_frame(&mut f).unwrap(), FrameStatus::End);
    }
}

mod replay_tests {
    use super::super::*;

    /// A generated source: frame i has value i and timestamp i / fps.
    struct Counter {
        info: SourceInfo,
        n: u64,
        i: u64,
        skip: Option<u64>,
    }

    impl Counter {
        fn new(n: u64, fps: f64) -> Self {
            Counter {
                info: SourceInfo {
                    name: "counter".into(),
                    width: 4,
                    height: 2,
                    fps,
                    has_color: false,
                    len: Some(n as usize),
                },
                n,
                i: 0,
                skip: None,
            }
        }
    }

    impl FrameSource for Counter {
        fn info(&self) -> &SourceInfo {
            &self.info
        }
        fn next_frame(&mut self, out: &mut Frame) -> Result<FrameStatus, SourceError> {
            if self.i >= self.n {
                return Ok(FrameStatus::End);
            }
            let i = self.i;
            self.i += 1;
            if self.skip == Some(i) {
                return Ok(FrameStatus::Skipped {
                    index: i,
                    reason: "bad".into(),
                });
            }
            out.gray.fill(i as u8);
            out.index = i;
            out.timestamp = i as f64 / self.info.fps;
            Ok(FrameStatus::Ready)
        }
    }

    #[test]
    fn as_fast_as_possible_delivers_every_frame_in_order() {
        let mut c = Counter::new(50, 30.0);
        c.skip = Some(7);
        let mut p = PacedSource::spawn(c, Pacing::AsFastAsPossible).unwrap();
        let mut f = Frame::new(4, 2);
        let mut seen = Vec::new();
        let mut skipped = 0;
        loop {
            match p.next_frame(&mut f).unwrap() {
                FrameStatus::Ready => {
                    seen.push(f.index);
                    std::thread::sleep(Duration::from_micros(200));
                }
                FrameStatus::Skipped { .. } => skipped += 1,
                FrameStatus::End => break,
            }
        }
        assert_eq!(skipped, 1);
        assert_eq!(seen.len(), 49);
        assert!(seen.windows(2).all(|w| w[1] > w[0]));
        assert_eq!(p.stats().dropped(), 0);
    }

    #[test]
    fn real_time_drops_oldest_for_slow_consumer_and_never_reorders() {
        let c = Counter::new(60, 200.0);
        let mut p = PacedSource::spawn(c, Pacing::RealTime { speed: 1.0 }).unwrap();
        let mut f = Frame::new(4, 2);
        let mut seen = Vec::new();
        while let FrameStatus::Ready = p.next_frame(&mut f).unwrap() {
            seen.push(f.index);
            assert!(f.arrival.is_some());
            std::thread::sleep(Duration::from_millis(20)); // 4x slower than the source
        }
        let dropped = p.stats().dropped();
        assert!(dropped > 20, "dropped {dropped}");
        assert_eq!(seen.len() as u64 + dropped, 60);
        assert!(seen.windows(2).all(|w| w[1] > w[0]));
        // Newest frames are kept: the last frame is always delivered.
        assert_eq!(*seen.last().unwrap(), 59);
    }

    #[test]
    fn real_time_releases_at_timestamps() {
        let c = Counter::new(10, 100.0);
        let mut p = PacedSource::spawn(c, Pacing::RealTime { speed: 1.0 }).unwrap();
        let mut f = Frame::new(4, 2);
        let t = Instant::now();
        let mut n = 0;
        while let FrameStatus::Ready = p.next_frame(&mut f).unwrap() {
            n += 1;
        }
        assert_eq!(n, 10);
        assert!(
            t.elapsed() >= Duration::from_millis(85),
            "{:?}",
            t.elapsed()
        );
    }

    /// A counter that notes when each frame was read.
    struct Timed(Counter, Arc<std::sync::Mutex<Vec<Instant>>>);

    impl FrameSource for Timed {
        fn info(&self) -> &SourceInfo {
            self.0.info()
        }
        fn next_frame(&mut self, out: &mut Frame) -> Result<FrameStatus, SourceError> {
            self.1.lock().unwrap().push(Instant::now());
            self.0.next_frame(out)
        }
    }

    #[test]
    fn real_time_reads_each_frame_shortly_before_it_is_due() {
        let reads = Arc::new(std::sync::Mutex::new(Vec::new()));
        let c = Timed(Counter::new(8, 20.0), Arc::clone(&reads));
        let mut p = PacedSource::spawn(c, Pacing::RealTime { speed: 1.0 }).unwrap();
        let mut f = Frame::new(4, 2);
        let mut released = Vec::new();
        while let FrameStatus::Ready = p.next_frame(&mut f).unwrap() {
            released.push(f.arrival.unwrap());
        }
        assert_eq!(released.len(), 8);
        let reads = reads.lock().unwrap();
        // From the third frame on (two releases give the interval), a read starts well after
        // the previous release (50 ms apart; a read takes microseconds here), not at once.
        for k in 2..8 {
            let gap = reads[k].duration_since(released[k - 1]);
            assert!(
                gap > Duration::from_millis(20),
                "frame {k}: read {gap:?} after the last release"
            );
            assert!(released[k] >= reads[k]);
        }
    }

    /// Runs `f` on a thread and fails the test when it has not returned within `limit`.
    fn within(limit: Duration, f: impl FnOnce() + Send + 'static) {
        let (tx, rx) = crossbeam_channel::bounded(1);
        std::thread::spawn(move || {
            f();
            let _ = tx.send(());
        });
        assert!(
            rx.recv_timeout(limit).is_ok(),
            "did not return within {limit:?}"
        );
    }

    #[test]
    fn dropping_mid_stream_joins_the_thread() {
        within(Duration::from_secs(10), || {
            let c = Counter::new(1_000_000, 1000.0);
            let mut p = PacedSource::spawn(c, Pacing::AsFastAsPossible).unwrap();
            let mut f = Frame::new(4, 2);
            p.next_frame(&mut f).unwrap();
            drop(p);
        });
    }

    /// Frame 0 at t = 0, then frames a day later (a gap, or nanosecond timestamps read as s).
    struct FarOff(Counter);
    impl FrameSource for FarOff {
        fn info(&self) -> &SourceInfo {
            &self.0.info
        }
        fn next_frame(&mut self, out: &mut Frame) -> Result<FrameStatus, SourceError> {
            let r = self.0.next_frame(out)?;
            if out.index > 0 {
                out.timestamp += 86_400.0;
            }
            Ok(r)
        }
    }

    static STOP_ASKED: AtomicBool = AtomicBool::new(false);

    #[test]
    fn an_interrupt_ends_a_wait_for_a_far_off_frame_and_drop_joins() {
        within(Duration::from_secs(5), || {
            let c = FarOff(Counter::new(10, 30.0));
            let mut p = PacedSource::spawn(c, Pacing::RealTime { speed: 1.0 }).unwrap();
            p.set_interrupt(|| STOP_ASKED.load(Ordering::SeqCst));
            let mut f = Frame::new(4, 2);
            assert_eq!(p.next_frame(&mut f).unwrap(), FrameStatus::Ready);
            std::thread::spawn(|| {
                std::thread::sleep(Duration::from_millis(200));
                STOP_ASKED.store(true, Ordering::SeqCst);
            });
            let t = Instant::now();
            assert_eq!(p.next_frame(&mut f).unwrap(), FrameStatus::End);
            assert!(t.elapsed() >= Duration::from_millis(150));
            drop(p); // the producer sleeps towards a day away: it must see the stop.
        });
    }
}
