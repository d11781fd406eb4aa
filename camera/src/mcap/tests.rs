use super::write::{BagImages, RosBagWriter};
use super::*;

fn frame(i: usize, color: bool) -> Frame {
    let (w, h) = (16u32, 8u32);
    let mut f = Frame::new(w, h);
    f.timestamp = 100.0 + i as f64 / 30.0;
    f.has_color = color;
    for (k, v) in f.rgb.iter_mut().enumerate() {
        *v = ((k * 13 + i * 31) % 251) as u8;
    }
    if color {
        crate::frame::gray_from_rgb(&mut f);
    } else {
        for (k, v) in f.gray.iter_mut().enumerate() {
            *v = ((k * 7 + i) % 256) as u8;
        }
    }
    f
}

fn info() -> CameraInfo {
    CameraInfo {
        width: 16,
        height: 8,
        distortion_model: "plumb_bob".into(),
        d: vec![0.1, 0.0, 0.0, 0.0, 0.0],
        k: [20.0, 0.0, 8.0, 0.0, 21.0, 4.0, 0.0, 0.0, 1.0],
        p: [0.0; 12],
    }
}

fn bag(dir: &Path, name: &str, images: BagImages, n: usize, color: bool) -> PathBuf {
    let path = dir.join(name);
    let file = std::io::BufWriter::new(File::create(&path).unwrap());
    let mut w = RosBagWriter::new(file, "/cam", images).unwrap();
    w.write_camera_info(100.0, &info()).unwrap();
    for i in 0..n {
        w.write_frame(&frame(i, color)).unwrap();
    }
    w.finish().unwrap();
    path
}

fn replay(src: &mut McapSource) -> Vec<Frame> {
    let mut out = Vec::new();
    let mut f = Frame::new(0, 0);
    while let FrameStatus::Ready = src.next_frame(&mut f).unwrap() {
        out.push(f.clone());
    }
    out
}

#[test]
fn raw_and_png_bags_replay_every_frame_exactly() {
    let d = tempfile::tempdir().unwrap();
    for (images, color) in [
        (BagImages::Raw, true),
        (BagImages::Raw, false),
        (BagImages::Png, true),
        (BagImages::Png, false),
    ] {
        let p = bag(d.path(), "b.mcap", images, 12, color);
        assert!(is_mcap(&p));
        let mut src = McapSource::open(&p, None, StampSource::Header).unwrap();
        assert_eq!(src.info().len, Some(12));
        assert_eq!((src.info().width, src.info().height), (16, 8));
        assert_eq!(src.info().has_color, color);
        assert!((src.info().fps - 30.0).abs() < 1e-6, "{}", src.info().fps);
        assert_eq!(src.camera_info(), Some(&info()));
        let frames = replay(&mut src);
        assert_eq!(frames.len(), 12, "{images:?}");
        for (i, f) in frames.iter().enumerate() {
            let want = frame(i, color);
            assert_eq!(f.gray, want.gray, "{images:?} colour {color} frame {i}");
            assert_eq!(f.index, i as u64);
            assert!((f.timestamp - want.timestamp).abs() < 1e-9);
        }
    }
}

#[test]
fn truncated_bag_keeps_the_frames_before_the_damage_and_names_the_offset() {
    let d = tempfile::tempdir().unwrap();
    // Uncompressed, unchunked records are readable one by one up to the cut.
    let p = d.path().join("t.mcap");
    let opts = mcap::WriteOptions::new().use_chunks(false);
    let file = std::io::BufWriter::new(File::create(&p).unwrap());
    let mut w = RosBagWriter::with_options(file, "/cam", BagImages::Raw, opts).unwrap();
    for i in 0..10 {
        w.write_frame(&frame(i, false)).unwrap();
    }
    w.finish().unwrap();
    let bytes = std::fs::read(&p).unwrap();
    let cut = d.path().join("cut.mcap");
    std::fs::write(&cut, &bytes[..bytes.len() * 4 / 10]).unwrap();
    match McapSource::open(&cut, None, StampSource::Header) {
        Ok(mut src) => {
            let mut f = Frame::new(0, 0);
            let mut n = 0;
            let err = loop {
                match src.next_frame(&mut f) {
                    Ok(FrameStatus::Ready) => n += 1,
                    Ok(other) => panic!("{other:?} after {n} frames"),
                    Err(e) => break e.to_string(),
                }
            };
            assert!(n < 10);
            assert!(err.contains("cut.mcap") && err.contains("bytes"), "{err}");
        }
        Err(e) => {
            // The writer's one chunk was cut: nothing before it is readable, and the
            // message says where reading stopped.
            let e = e.to_string();
            assert!(e.contains("cut.mcap"), "{e}");
        }
    }
    // Garbage is refused with the file's name.
    let junk = d.path().join("junk.mcap");
    std::fs::write(&junk, b"\x89MCAP0\r\nnonsense").unwrap();
    let e = McapSource::open(&junk, None, StampSource::Header)
        .err()
        .unwrap()
        .to_string();
    assert!(e.contains("junk.mcap"), "{e}");
}

#[test]
fn topic_choice_lists_what_the_file_has() {
    let d = tempfile::tempdir().unwrap();
    let p = bag(d.path(), "b.mcap", BagImages::Raw, 3, false);
    let e = McapSource::open(&p, Some("/nope"), StampSource::Header)
        .err()
        .unwrap()
        .to_string();
    assert!(
        e.contains("no topic `/nope`")
            && e.contains("/cam/image_raw (sensor_msgs/msg/Image, 3 messages)")
            && e.contains("/cam/camera_info"),
        "{e}"
    );
    let e = McapSource::open(&p, Some("/cam/camera_info"), StampSource::Header)
        .err()
        .unwrap()
        .to_string();
    assert!(e.contains("not images"), "{e}");
    let src = McapSource::open(&p, Some("/cam/image_raw"), StampSource::LogTime).unwrap();
    assert_eq!(src.topic(), "/cam/image_raw");
    assert!(src.info().name.contains("log times"));
}
