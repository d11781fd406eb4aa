//! Readers and calibration on the real files of `../shared/data` (TUM layout, EuRoC real camera).

mod common;

use sdslam::camera::{files::ListKind, Frame, FrameSource, FrameStatus, ImageListSource};
use sdslam::camera_model::RectifyMap;
use sdslam::io::{load_calibration, read_tum_trajectory};

#[test]
fn tum_synthetic_desk_reads_frames_calibration_and_ground_truth() {
    let Some(data) = common::shared_data() else {
        return;
    };
    let dir = data.join("synthetic/desk");
    let mut src = ImageListSource::open(&dir).unwrap();
    assert_eq!(src.kind(), ListKind::Tum);
    let info = src.info().clone();
    assert_eq!((info.width, info.height, info.len), (640, 480, Some(600)));
    assert!(info.has_color);
    assert!((info.fps - 30.0).abs() < 0.01);
    let calib = load_calibration(&dir.join("camera.yaml")).unwrap();
    assert_eq!(calib.camera.fx, 520.0);
    calib
        .check_image_size(info.width, info.height, "camera.yaml")
        .unwrap();
    let mut f = Frame::new(640, 480);
    for i in 0..3 {
        assert_eq!(src.next_frame(&mut f).unwrap(), FrameStatus::Ready);
        assert_eq!(f.index, i);
        assert!(f.has_color);
        let mean = f.gray.iter().map(|&v| v as f64).sum::<f64>() / f.gray.len() as f64;
        assert!(mean > 20.0 && mean < 235.0, "mean {mean}");
    }
    let gt = read_tum_trajectory(&dir.join("groundtruth.txt")).unwrap();
    assert_eq!(gt.len(), 600);
    assert!((gt[1].timestamp - gt[0].timestamp - 1.0 / 30.0).abs() < 1e-5);
}

#[test]
fn euroc_micro_reads_real_frames_and_radtan_calibration() {
    let Some(data) = common::shared_data() else {
        return;
    };
    let dir = data.join("euroc_v101_micro");
    let mut src = ImageListSource::open(&dir).unwrap();
    assert_eq!(src.kind(), ListKind::Euroc);
    let info = src.info().clone();
    assert_eq!((info.width, info.height, info.len), (752, 480, Some(30)));
    assert!(!info.has_color);
    assert!((info.fps - 20.0).abs() < 0.01);
    let calib = load_calibration(&dir.join("mav0/cam0/sensor.yaml")).unwrap();
    let cam = calib.camera;
    assert_eq!(
        (cam.fx, cam.fy, cam.cx, cam.cy),
        (458.654, 457.296, 367.215, 248.375)
    );
    assert_eq!(
        (cam.k1, cam.k2, cam.p1, cam.p2),
        (-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05)
    );
    assert!(!cam.is_distortion_free());

    // Rectify every frame into a preallocated buffer; barrel distortion of k1 < 0 pulls the
    // image corners in, so rectified corners map outside the source and stay black, while the
    // centre keeps real content.
    let map = RectifyMap::new(&cam);
    let mut f = Frame::new(752, 480);
    let mut rect = vec![0u8; 752 * 480];
    let mut n = 0;
    let mut prev_ts = f64::NEG_INFINITY;
    while let FrameStatus::Ready = src.next_frame(&mut f).unwrap() {
        assert!(f.timestamp > prev_ts);
        prev_ts = f.timestamp;
        map.remap_gray(&f.gray, &mut rect);
        n += 1;
    }
    assert_eq!(n, 30);
    let centre: f64 = (200..280)
        .flat_map(|y| (336..416).map(move |x| (x, y)))
        .map(|(x, y)| rect[y * 752 + x] as f64)
        .sum::<f64>()
        / 6400.0;
    assert!(centre > 10.0, "centre mean {centre}");
    // The undistorted image corner lies outside the distorted image for this lens.
    let d = cam.distort_pixel(0.0, 0.0);
    assert!(d.x > 0.0 && d.y > 0.0, "{d:?}");
    // Undistortion of real-lens points round-trips.
    for (u, v) in [(10.0, 10.0), (740.0, 470.0), (367.0, 248.0)] {
        let p = cam.undistort_pixel(u, v);
        let back = cam.distort_pixel(p.x, p.y);
        assert!((back.x - u).abs() < 1e-6 && (back.y - v).abs() < 1e-6);
    }
}

#[test]
fn shipped_calibration_files_parse() {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("calib");
    let mut n = 0;
    for e in std::fs::read_dir(&dir).unwrap() {
        let p = e.unwrap().path();
        if p.extension().is_some_and(|x| x == "yaml") {
            let c = load_calibration(&p).unwrap_or_else(|e| panic!("{e}"));
            assert!(c.camera.fx > 100.0, "{}", p.display());
            n += 1;
        }
    }
    assert!(
        n >= 5,
        "expected calibration files for TUM fr1/2/3, EuRoC, synthetic; found {n}"
    );
}

/// A 12-bit or 10-bit camera's frames saved as 16-bit PNGs read as the same grey image as the
/// 8-bit original (the high byte alone would be grey levels 0-15, on which nothing tracks).
#[test]
fn sixteen_bit_pngs_of_a_10_or_12_bit_camera_read_like_the_8_bit_original() {
    let d = tempfile::tempdir().unwrap();
    let (w, h) = (64u32, 48u32);
    // Three frames of texture over the whole grey range (a hash of the pixel and frame).
    let originals: Vec<Vec<u8>> = (0..3u32)
        .map(|i| {
            (0..w * h)
                .map(|p| ((p.wrapping_mul(2_654_435_761) ^ (i * 977)) >> 7) as u8)
                .collect()
        })
        .collect();
    let mut f = Frame::new(w, h);
    assert_eq!(originals.len(), 3);
    for (bits, name) in [(12u32, "twelve"), (10, "ten")] {
        let dir = d.path().join(name);
        std::fs::create_dir_all(dir.join("rgb")).unwrap();
        let mut list = String::new();
        for (i, g) in originals.iter().enumerate() {
            let img = image::ImageBuffer::<image::Luma<u16>, Vec<u16>>::from_fn(w, h, |x, y| {
                let v = g[(y * w + x) as usize] as u16;
                image::Luma([(v << (bits - 8)) | 1])
            });
            img.save(dir.join(format!("rgb/{i}.png"))).unwrap();
            list += &format!("{}.0 rgb/{i}.png\n", i + 1);
        }
        std::fs::write(dir.join("rgb.txt"), list).unwrap();
        let mut src = ImageListSource::open(&dir).unwrap();
        for (i, g) in originals.iter().enumerate() {
            assert_eq!(src.next_frame(&mut f).unwrap(), FrameStatus::Ready);
            assert!(!f.has_color);
            assert!(
                f.gray == *g,
                "{bits}-bit frame {i} differs from the original"
            );
        }
    }
}
