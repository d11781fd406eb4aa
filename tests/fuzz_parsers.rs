//! Fuzzing of every parser of external input, on the stable toolchain (cargo-fuzz needs
//! nightly, which this project's machines do not have): property tests that mutate real files
//! (bit flips, byte edits, deletions, insertions of tokens parsers find hard, truncation) and
//! require a clean `Ok` or `Err` (never a panic), plus sanity of what is accepted. The number
//! of cases per target is `SDSLAM_FUZZ_CASES` (default 20,000); docs/RELIABILITY.md records runs.

mod common;

use std::path::{Path, PathBuf};

use proptest::prelude::*;
use proptest::test_runner::{Config as PtConfig, TestRunner};

use sdslam::camera::list::{parse_euroc, parse_timestamps, parse_tum};
use sdslam::camera_model::Calibration;
use sdslam::config::Config;
use sdslam::io::{decode_ply, encode_ply, parse_tum_trajectory, CloudPoint};
use sdslam::place_recognition::{decode_vocabulary, encode_vocabulary, parse_dbow2_text};

/// Tokens that exercise number parsing and structure.
const TOKENS: &[&str] = &[
    "nan",
    "inf",
    "-inf",
    "1e309",
    "-1",
    "0",
    "\n",
    "#",
    ",",
    ":",
    " ",
    "\"",
    "[",
    "]",
    "=",
    "\0",
    "\u{FEFF}",
    "9999999999999999999",
];

type Op = (u8, usize, u8);

fn ops() -> impl Strategy<Value = Vec<Op>> {
    proptest::collection::vec((0u8..6, any::<usize>(), any::<u8>()), 1..10)
}

fn mutate(seed: &[u8], ops: &[Op]) -> Vec<u8> {
    let mut v = seed.to_vec();
    for &(kind, pos, byte) in ops {
        let n = v.len();
        let at = if n == 0 { 0 } else { pos % (n + 1) };
        match kind {
            0 if n > 0 => v[at.min(n - 1)] ^= 1 << (byte % 8),
            1 if n > 0 => v[at.min(n - 1)] = byte,
            2 if n > 0 => {
                let end = (at + 1 + byte as usize % 16).min(n);
                v.drain(at.min(n - 1)..end);
            }
            3 => {
                let t = TOKENS[byte as usize % TOKENS.len()].as_bytes();
                v.splice(at..at, t.iter().copied());
            }
            4 => v.truncate(at),
            _ => v.insert(at, byte),
        }
    }
    v
}

fn cases() -> u32 {
    std::env::var("SDSLAM_FUZZ_CASES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(20_000)
}

/// Runs `check` on mutations of each seed; returns the number of executions.
fn fuzz(name: &str, seeds: &[Vec<u8>], check: impl Fn(&[u8])) -> u64 {
    assert!(!seeds.is_empty(), "{name}: no seed inputs");
    let mut runner = TestRunner::new(PtConfig {
        cases: cases(),
        failure_persistence: None,
        ..PtConfig::default()
    });
    let seeds_len = seeds.len();
    let strategy = (0..seeds_len, ops());
    let count = std::cell::Cell::new(0u64);
    let r = runner.run(&strategy, |(s, ops)| {
        let input = mutate(&seeds[s], &ops);
        check(&input);
        count.set(count.get() + 1);
        Ok(())
    });
    if let Err(e) = r {
        panic!("{name}: {e}");
    }
    // The seeds themselves must parse.
    eprintln!("fuzz {name}: {} executions", count.get());
    count.get()
}

fn read(p: impl AsRef<Path>) -> Vec<u8> {
    std::fs::read(p.as_ref()).unwrap_or_else(|e| panic!("{}: {e}", p.as_ref().display()))
}

fn text(b: &[u8]) -> String {
    String::from_utf8_lossy(b).into_owned()
}

fn repo(p: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join(p)
}

#[test]
fn fuzz_calibration_yaml() {
    let mut seeds: Vec<Vec<u8>> = std::fs::read_dir(repo("calib"))
        .unwrap()
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|e| e == "yaml"))
        .map(read)
        .collect();
    if let Some(d) = common::shared_data() {
        seeds.push(read(d.join("euroc_v101_micro/mav0/cam0/sensor.yaml")));
    }
    for s in &seeds {
        Calibration::parse(&text(s), "seed").expect("seed calibrations parse");
    }
    fuzz("calibration", &seeds, |b| {
        if let Ok(c) = Calibration::parse(&text(b), "fuzz.yaml") {
            let k = c.camera;
            for v in [k.fx, k.fy, k.cx, k.cy, k.k1, k.k2, k.p1, k.p2, k.k3, c.fps] {
                assert!(v.is_finite(), "accepted a non-finite value: {c:?}");
            }
            assert!(
                k.fx > 0.0 && k.fy > 0.0 && k.width > 0 && k.height > 0 && c.fps > 0.0,
                "{c:?}"
            );
        }
    });
}

fn check_list(entries: &[sdslam::camera::list::ListEntry]) {
    for w in entries.windows(2) {
        assert!(
            w[1].timestamp > w[0].timestamp,
            "accepted non-increasing timestamps"
        );
    }
    assert!(
        entries.iter().all(|e| e.timestamp.is_finite()),
        "accepted a non-finite timestamp"
    );
}

#[test]
fn fuzz_image_lists() {
    let Some(d) = common::shared_data() else {
        return;
    };
    let tum: Vec<u8> = read(d.join("synthetic/desk/rgb.txt"))
        .into_iter()
        .take(4000)
        .collect();
    let euroc = read(d.join("euroc_v101_micro/mav0/cam0/data.csv"));
    let p = Path::new("list");
    fuzz("tum rgb.txt", &[tum], |b| {
        if let Ok(l) = parse_tum(&text(b), p) {
            check_list(&l);
        }
    });
    fuzz("euroc data.csv", &[euroc], |b| {
        if let Ok(l) = parse_euroc(&text(b), p) {
            check_list(&l);
        }
    });
    let images: Vec<PathBuf> = (0..5).map(|i| PathBuf::from(format!("{i}.png"))).collect();
    let times = b"0.0\n0.033\n0.066\n0.1\n0.133\n".to_vec();
    let named = b"# t file\n1.5 0.png\n1.6 1.png\n1.7 2.png\n".to_vec();
    fuzz("times.txt", &[times, named], |b| {
        if let Ok(l) = parse_timestamps(&text(b), p, &images) {
            check_list(&l);
        }
    });
}

#[test]
fn fuzz_trajectories() {
    let Some(d) = common::shared_data() else {
        return;
    };
    let gt: Vec<u8> = text(&read(d.join("synthetic/desk/groundtruth.txt")))
        .lines()
        .take(40)
        .collect::<Vec<_>>()
        .join("\n")
        .into_bytes();
    fuzz("tum trajectory", &[gt], |b| {
        if let Ok(t) = parse_tum_trajectory(&text(b), Path::new("traj.txt")) {
            for p in &t {
                assert!(p.timestamp.is_finite());
                let m = p.t_wc.0.to_homogeneous();
                assert!(
                    m.iter().all(|v| v.is_finite()),
                    "accepted a non-finite pose"
                );
            }
        }
    });
}

#[test]
fn fuzz_vocabularies() {
    // A small trained vocabulary (fast cases) and the shipped default.
    let default = read(repo("src/place_recognition/default_vocabulary.sdsvoc"));
    let v = decode_vocabulary(&default).expect("default vocabulary decodes");
    assert_eq!(encode_vocabulary(&v), default, "encode(decode(x)) == x");
    fuzz("vocabulary (binary)", &[default], |b| {
        let _ = decode_vocabulary(b);
    });
    if let Some(d) = common::shared_data() {
        let txt = read(d.join("vocab/wangzheqie_voc_orbslam2_txt.txt"));
        parse_dbow2_text(&text(&txt)).expect("seed DBoW2 text parses");
        fuzz("vocabulary (DBoW2 text)", &[txt], |b| {
            let _ = parse_dbow2_text(&text(b));
        });
    }
}

#[test]
fn fuzz_ply_and_round_trip() {
    let pts = |n: usize| -> Vec<CloudPoint> {
        (0..n)
            .map(|i| CloudPoint {
                position: [i as f32 * 0.5, -(i as f32), 1.0 / (i as f32 + 1.0)],
                rgb: [i as u8, 255 - i as u8, 7],
                sigma: 0.01 * i as f32,
                timestamp: 1.7e9 + i as f64 / 30.0,
            })
            .collect()
    };
    let seed = encode_ply(&pts(20));
    let back = decode_ply(&seed, Path::new("a.ply")).unwrap();
    assert_eq!(back.len(), 20);
    for (a, b) in back.iter().zip(pts(20)) {
        assert_eq!(
            (a.position, a.rgb, a.sigma, a.timestamp),
            (b.position, b.rgb, b.sigma, b.timestamp)
        );
    }
    assert!(decode_ply(&encode_ply(&[]), Path::new("e.ply"))
        .unwrap()
        .is_empty());
    fuzz("ply", &[seed], |b| {
        if let Ok(p) = decode_ply(b, Path::new("f.ply")) {
            // Whatever is accepted re-encodes to something that decodes to the same points.
            let again = decode_ply(&encode_ply(&p), Path::new("g.ply")).unwrap();
            assert_eq!(again.len(), p.len());
        }
    });
}

#[test]
fn fuzz_config_toml() {
    let seed = b"[orb]\nn_features = 1000\nscale_factor = 1.2\nn_levels = 8\n\n[semidense]\nenabled = true\nlambda_n = 3\n\n[runtime]\nrealtime_speed = 1.0\n".to_vec();
    let base = Config::parse(&text(&seed), Path::new("seed.toml"));
    assert!(
        base.is_ok(),
        "seed config parses: {:?}",
        base.err().map(|e| e.to_string())
    );
    fuzz("config toml", &[seed], |b| {
        let _ = Config::parse(&text(b), Path::new("fuzz.toml"));
    });
}

#[test]
fn fuzz_images_and_camera_buffers() {
    use sdslam::camera::decode::ImageDecoderBuf;
    use sdslam::camera::device::convert::{encode, Converter};
    use sdslam::camera::device::PixelFormat;
    use sdslam::camera::Frame;
    let (w, h) = (48u32, 32u32);
    let rgb: Vec<u8> = (0..w * h * 3).map(|i| (i * 37 % 251) as u8).collect();
    let mut png = Vec::new();
    image::RgbImage::from_raw(w, h, rgb.clone())
        .unwrap()
        .write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png)
        .unwrap();
    let mut jpeg = Vec::new();
    encode::jpeg_from_rgb(&rgb, w, h, &mut jpeg).unwrap();
    let uvc = encode::strip_huffman_tables(&jpeg);
    let dec = std::cell::RefCell::new((ImageDecoderBuf::new(), Frame::new(w, h)));
    fuzz("png/jpeg files", &[png, jpeg.clone()], |b| {
        let (d, f) = &mut *dec.borrow_mut();
        if d.decode(b, Path::new("fuzz.img"), Some((w, h)), f).is_ok() {
            assert_eq!((f.width, f.height), (w, h));
        }
    });
    let conv = std::cell::RefCell::new((
        Converter::new("fuzzcam", PixelFormat::Mjpeg, w, h, 0, true),
        Frame::new(w, h),
    ));
    fuzz("mjpeg camera buffers", &[uvc, jpeg], |b| {
        let (c, f) = &mut *conv.borrow_mut();
        let _ = c.convert(b, f);
    });
    let mut yuyv = Vec::new();
    encode::yuyv_from_rgb(&rgb, w as usize, h as usize, 2 * w as usize, &mut yuyv);
    let conv = std::cell::RefCell::new((
        Converter::new("fuzzcam", PixelFormat::Yuyv, w, h, 0, true),
        Frame::new(w, h),
    ));
    fuzz("yuyv camera buffers", &[yuyv], |b| {
        let (c, f) = &mut *conv.borrow_mut();
        let _ = c.convert(b, f);
    });
}

#[test]
fn fuzz_map_files() {
    use sdslam::map::persist::MapSnapshot;
    use sdslam::runtime::System;
    use sdslam::synthetic::{SyntheticConfig, SyntheticSequence};
    let seq = SyntheticSequence::new(SyntheticConfig::default());
    let c = &seq.config;
    let mut cfg = Config::default();
    cfg.semidense.enabled = false;
    let mut s = System::new(&c.calibration(), &cfg, 60, false);
    let mut f = sdslam::camera::Frame::new(c.width, c.height);
    for i in 0..60 {
        seq.render_frame(i, &mut f);
        s.process(&f.gray, None, f.timestamp, i as u64);
    }
    assert!(s.finish());
    let seed = s.save_map().encode().unwrap();
    assert!(MapSnapshot::decode(&seed).is_ok());
    fuzz("map file", std::slice::from_ref(&seed), |b| {
        let _ = MapSnapshot::decode(b);
    });
    // Past the checksum: mutate the payload, re-seal the header, and load whatever decodes into
    // a system (validation must catch every inconsistency; nothing may panic).
    let payload = seed[24..].to_vec();
    let target = std::cell::RefCell::new(System::new(&c.calibration(), &cfg, 10, false));
    fuzz("map payload (re-sealed)", &[payload], |p| {
        let mut file = seed[..12].to_vec();
        file.extend_from_slice(&(p.len() as u64).to_le_bytes());
        file.extend_from_slice(&crc32fast::hash(p).to_le_bytes());
        file.extend_from_slice(p);
        if let Ok(snap) = MapSnapshot::decode(&file) {
            let _ = target.borrow_mut().load_map(&snap);
        }
    });
}
