//! Frame input costs: JPEG decode into a reused frame, rectification of a distorted image,
//! and one synthetic render.

use std::io::Cursor;
use std::path::Path;

use criterion::{criterion_group, criterion_main, Criterion};
use sdslam::camera::decode::ImageDecoderBuf;
use sdslam::camera::Frame;
use sdslam::camera_model::{PinholeRadtan, RectifyMap};
use sdslam::synthetic::{SyntheticConfig, SyntheticSequence};

fn frames(c: &mut Criterion) {
    sdslam::simd::cap_from_env().expect("SDSLAM_SIMD");
    let seq = SyntheticSequence::new(SyntheticConfig {
        frames: 10,
        ..SyntheticConfig::default()
    });
    let mut f = Frame::new(640, 480);
    seq.render_frame(0, &mut f);
    let mut jpeg = Vec::new();
    image::RgbImage::from_raw(640, 480, f.rgb.clone())
        .expect("buffer size")
        .write_to(&mut Cursor::new(&mut jpeg), image::ImageFormat::Jpeg)
        .expect("encode");
    let mut dec = ImageDecoderBuf::new();
    let mut out = Frame::new(640, 480);
    c.bench_function("decode_jpeg_640x480_into_frame", |b| {
        b.iter(|| {
            dec.decode(&jpeg, Path::new("bench.jpg"), Some((640, 480)), &mut out)
                .expect("decode")
        })
    });
    let cam = PinholeRadtan {
        k1: 0.262383,
        k2: -0.953104,
        p1: -0.005358,
        p2: 0.002628,
        k3: 1.163314,
        ..PinholeRadtan::pinhole(517.3, 516.5, 318.6, 255.3, 640, 480)
    };
    // Camera conversions (issue 10): device buffer -> preallocated grey frame.
    {
        use sdslam::camera::device::convert::{encode, Converter};
        use sdslam::camera::device::PixelFormat;
        let mut yuyv = Vec::new();
        encode::yuyv_from_rgb(&f.rgb, 640, 480, 1280, &mut yuyv);
        let uvc_mjpeg = encode::strip_huffman_tables(&jpeg);
        let mut g = c.benchmark_group("camera_convert_640x480");
        for (name, format, data, colour) in [
            ("yuyv_to_grey", PixelFormat::Yuyv, &yuyv, false),
            ("yuyv_to_grey_and_rgb", PixelFormat::Yuyv, &yuyv, true),
            (
                "mjpeg_to_grey_and_rgb",
                PixelFormat::Mjpeg,
                &uvc_mjpeg,
                true,
            ),
        ] {
            let mut conv = Converter::new("bench", format, 640, 480, 0, colour);
            g.bench_function(name, |b| {
                b.iter(|| conv.convert(data, &mut out).expect("convert"))
            });
        }
        g.finish();
    }
    mcap_replay(c, &seq);
    let map = RectifyMap::new(&cam);
    let mut dst = vec![0u8; 640 * 480];
    c.bench_function("rectify_gray_640x480", |b| {
        b.iter(|| map.remap_gray(&f.gray, &mut dst))
    });
    let mut dst_rgb = vec![0u8; 640 * 480 * 3];
    c.bench_function("rectify_rgb_640x480", |b| {
        b.iter(|| map.remap_rgb(&f.rgb, &mut dst_rgb))
    });
    let mut g = c.benchmark_group("synthetic");
    g.sample_size(10);
    g.bench_function("render_640x480", |b| {
        b.iter(|| seq.render_frame(5, &mut out))
    });
    g.finish();
}

/// MCAP replay cost per 640x480 frame (issue 28: <= 1 ms): a ROS 2 bag of 10 rendered frames
/// (zstd or lz4 chunks, or none), read frame by frame into a reused frame; the
/// open (scan of the file) is outside the timing.
fn mcap_replay(c: &mut Criterion, seq: &SyntheticSequence) {
    use sdslam::camera::mcap::write::{BagImages, RosBagWriter};
    use sdslam::camera::mcap::{McapSource, StampSource};
    use sdslam::camera::{FrameSource, FrameStatus};
    let dir = tempfile::tempdir().expect("tempdir");
    let mut g = c.benchmark_group("mcap_replay_640x480");
    use mcap::Compression::{Lz4, Zstd};
    for (name, images, colour, compression) in [
        ("ros_image_rgb8_zstd", BagImages::Raw, true, Some(Zstd)),
        ("ros_image_rgb8_lz4", BagImages::Raw, true, Some(Lz4)),
        ("ros_image_rgb8_uncompressed", BagImages::Raw, true, None),
        ("ros_image_mono8_zstd", BagImages::Raw, false, Some(Zstd)),
        ("ros_image_mono8_lz4", BagImages::Raw, false, Some(Lz4)),
        ("ros_compressed_png_rgb", BagImages::Png, true, None),
        ("ros_compressed_jpeg_rgb", BagImages::Jpeg, true, None),
    ] {
        let path = dir.path().join(format!("{name}.mcap"));
        let file = std::io::BufWriter::new(std::fs::File::create(&path).expect("create"));
        let opts = mcap::WriteOptions::new().compression(compression);
        let mut w = RosBagWriter::with_options(file, "/camera", images, opts).expect("writer");
        let mut f = Frame::new(640, 480);
        for i in 0..10 {
            seq.render_frame(i, &mut f);
            f.has_color = colour;
            w.write_frame(&f).expect("write");
        }
        w.finish().expect("finish");
        let mut out = Frame::new(640, 480);
        g.bench_function(name, |b| {
            b.iter_custom(|iters| {
                let mut total = std::time::Duration::ZERO;
                let mut src = McapSource::open(&path, None, StampSource::Header).expect("open");
                for _ in 0..iters {
                    let t = std::time::Instant::now();
                    let mut status = src.next_frame(&mut out).expect("read");
                    total += t.elapsed();
                    if status == FrameStatus::End {
                        src = McapSource::open(&path, None, StampSource::Header).expect("open");
                        let t = std::time::Instant::now();
                        status = src.next_frame(&mut out).expect("read");
                        total += t.elapsed();
                    }
                    assert_eq!(status, FrameStatus::Ready);
                }
                total
            })
        });
    }
    g.finish();
}

criterion_group!(benches, frames);
criterion_main!(benches);
