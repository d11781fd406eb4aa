//! The image and calibration messages an MCAP replay understands: ROS 2 `sensor_msgs/msg/Image`,
//! `CompressedImage` and `CameraInfo` (CDR), and Foxglove's `foxglove.RawImage` and
//! `foxglove.CompressedImage` (protobuf, as the Foxglove SDK writes them).

use super::cdr::CdrReader;
use crate::device::convert::{yuyv_to_grey, yuyv_to_rgb};
use crate::frame::gray_from_rgb;
use crate::Frame;

/// Which image message a channel carries.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ImageSchema {
    RosImage,
    RosCompressedImage,
    FoxgloveRawImage,
    FoxgloveCompressedImage,
}

impl ImageSchema {
    /// Recognises an image channel from its schema name and message encoding. `Err` for an
    /// image schema in an encoding this reader does not decode.
    pub fn of(schema_name: &str, message_encoding: &str) -> Option<Result<Self, String>> {
        let name = schema_name.replace("/msg/", "/");
        let (schema, want) = match name.as_str() {
            "sensor_msgs/Image" => (ImageSchema::RosImage, "cdr"),
            "sensor_msgs/CompressedImage" => (ImageSchema::RosCompressedImage, "cdr"),
            "foxglove.RawImage" => (ImageSchema::FoxgloveRawImage, "protobuf"),
            "foxglove.CompressedImage" => (ImageSchema::FoxgloveCompressedImage, "protobuf"),
            _ => return None,
        };
        Some(if message_encoding == want {
            Ok(schema)
        } else {
            Err(format!(
                "{schema_name} in `{message_encoding}` encoding is not supported (only `{want}`)"
            ))
        })
    }

    pub fn is_camera_info(schema_name: &str) -> bool {
        matches!(
            schema_name,
            "sensor_msgs/msg/CameraInfo" | "sensor_msgs/CameraInfo"
        )
    }
}

/// The pixels of one image message, borrowed from the record.
#[derive(Debug, PartialEq)]
pub enum ImagePayload<'a> {
    Raw {
        width: u32,
        height: u32,
        encoding: &'a str,
        big_endian: bool,
        step: u32,
        data: &'a [u8],
    },
    /// `format` as the message states it (`jpeg`, `png`, `rgb8; jpeg compressed bgr8`).
    Compressed { format: &'a str, data: &'a [u8] },
}

/// One decoded image message: its header stamp (seconds; `None` when zero or absent) and
/// pixels.
#[derive(Debug, PartialEq)]
pub struct ImageMsg<'a> {
    pub stamp: Option<f64>,
    pub payload: ImagePayload<'a>,
}

/// Decodes an image message's envelope (not its pixels).
pub fn decode_image(schema: ImageSchema, data: &[u8]) -> Result<ImageMsg<'_>, String> {
    match schema {
        ImageSchema::RosImage => {
            let mut r = CdrReader::new(data).map_err(|e| e.to_string())?;
            let (stamp, _) = r.header().map_err(|e| e.to_string())?;
            let height = r.u32("height").map_err(|e| e.to_string())?;
            let width = r.u32("width").map_err(|e| e.to_string())?;
            let encoding = r.string("encoding").map_err(|e| e.to_string())?;
            let big_endian = r.u8("is_bigendian").map_err(|e| e.to_string())? != 0;
            let step = r.u32("step").map_err(|e| e.to_string())?;
            let data = r.bytes("data").map_err(|e| e.to_string())?;
            Ok(ImageMsg {
                stamp: nonzero(stamp),
                payload: ImagePayload::Raw {
                    width,
                    height,
                    encoding,
                    big_endian,
                    step,
                    data,
                },
            })
        }
        ImageSchema::RosCompressedImage => {
            let mut r = CdrReader::new(data).map_err(|e| e.to_string())?;
            let (stamp, _) = r.header().map_err(|e| e.to_string())?;
            let format = r.string("format").map_err(|e| e.to_string())?;
            let data = r.bytes("data").map_err(|e| e.to_string())?;
            Ok(ImageMsg {
                stamp: nonzero(stamp),
                payload: ImagePayload::Compressed { format, data },
            })
        }
        ImageSchema::FoxgloveRawImage => {
            let (mut stamp, mut width, mut height, mut step) = (None, 0, 0, 0);
            let (mut encoding, mut pixels) = ("", &[][..]);
            for field in ProtoFields(data) {
                match field? {
                    (1, Proto::Bytes(b)) => stamp = proto_timestamp(b)?,
                    (2, Proto::Fixed32(v)) => width = v,
                    (3, Proto::Fixed32(v)) => height = v,
                    (4, Proto::Bytes(b)) => encoding = utf8(b, "encoding")?,
                    (5, Proto::Fixed32(v)) => step = v,
                    (6, Proto::Bytes(b)) => pixels = b,
                    _ => {}
                }
            }
            Ok(ImageMsg {
                stamp,
                payload: ImagePayload::Raw {
                    width,
                    height,
                    encoding,
                    big_endian: false,
                    step,
                    data: pixels,
                },
            })
        }
        ImageSchema::FoxgloveCompressedImage => {
            let (mut stamp, mut format, mut bytes) = (None, "", &[][..]);
            for field in ProtoFields(data) {
                match field? {
                    (1, Proto::Bytes(b)) => stamp = proto_timestamp(b)?,
                    (2, Proto::Bytes(b)) => bytes = b,
                    (3, Proto::Bytes(b)) => format = utf8(b, "format")?,
                    _ => {}
                }
            }
            Ok(ImageMsg {
                stamp,
                payload: ImagePayload::Compressed {
                    format,
                    data: bytes,
                },
            })
        }
    }
}

fn nonzero(t: f64) -> Option<f64> {
    (t != 0.0).then_some(t)
}

fn utf8<'a>(b: &'a [u8], what: &str) -> Result<&'a str, String> {
    std::str::from_utf8(b).map_err(|_| format!("{what} is not UTF-8"))
}

/// Writes raw pixels into `out` (grey, and RGB for colour encodings); 16-bit ones at the
/// source's significant bits (`wide`). The arguments are a ROS `sensor_msgs/Image`'s fields.
#[allow(clippy::too_many_arguments)]
pub fn raw_to_frame(
    width: u32,
    height: u32,
    encoding: &str,
    big_endian: bool,
    step: u32,
    data: &[u8],
    wide: &mut crate::decode::WideSamples,
    out: &mut Frame,
) -> Result<(), String> {
    if width == 0 || height == 0 {
        return Err(format!("image has zero size {width}x{height}"));
    }
    if width as u64 * height as u64 > crate::decode::MAX_PIXELS {
        return Err(format!("image claims {width}x{height} pixels"));
    }
    let enc = encoding.to_ascii_lowercase();
    let bpp = match enc.as_str() {
        "mono8" | "8uc1" => 1,
        "mono16" | "16uc1" | "yuv422" | "uyvy" | "yuv422_yuy2" | "yuyv" => 2,
        "rgb8" | "bgr8" | "8uc3" => 3,
        "rgba8" | "bgra8" | "8uc4" => 4,
        _ => {
            return Err(format!(
                "pixel encoding `{encoding}` is not supported (mono8, mono16, rgb8, bgr8, rgba8, bgra8, yuv422, yuv422_yuy2)"
            ))
        }
    };
    let (w, h, step) = (width as usize, height as usize, step as usize);
    if step < w * bpp || data.len() < step * (h - 1) + w * bpp {
        return Err(format!(
            "{width}x{height} {encoding} needs a step of at least {} and {} bytes; the message has step {step} and {} bytes",
            w * bpp,
            step * (h - 1) + w * bpp,
            data.len()
        ));
    }
    out.ensure_size(width, height);
    let rows = |r: usize| &data[r * step..r * step + w * bpp];
    match enc.as_str() {
        "mono8" | "8uc1" => {
            for (r, dst) in out.gray.chunks_exact_mut(w).enumerate() {
                dst.copy_from_slice(rows(r));
            }
            out.has_color = false;
        }
        "mono16" | "16uc1" => {
            let sample = |px: &[u8]| {
                if big_endian {
                    u16::from_be_bytes([px[0], px[1]])
                } else {
                    u16::from_le_bytes([px[0], px[1]])
                }
            };
            let shift = wide.shift(|| {
                (0..h)
                    .flat_map(|r| rows(r).chunks_exact(2).map(sample))
                    .max()
                    .unwrap_or(0)
            });
            for (r, dst) in out.gray.chunks_exact_mut(w).enumerate() {
                for (d, px) in dst.iter_mut().zip(rows(r).chunks_exact(2)) {
                    *d = crate::decode::WideSamples::to_u8(shift, sample(px));
                }
            }
            out.has_color = false;
        }
        "yuv422_yuy2" | "yuyv" => {
            yuyv_to_grey(data, step, w, h, &mut out.gray);
            yuyv_to_rgb(data, step, w, h, &mut out.rgb);
            out.has_color = true;
        }
        "yuv422" | "uyvy" => {
            // UYVY: the same pixels as YUYV with the byte pairs swapped.
            for r in 0..h {
                let line = rows(r);
                let g = &mut out.gray[r * w..(r + 1) * w];
                for (d, px) in g.iter_mut().zip(line.chunks_exact(2)) {
                    *d = px[1];
                }
                let dst = &mut out.rgb[3 * r * w..3 * (r + 1) * w];
                for (d, q) in dst.chunks_exact_mut(6).zip(line.chunks_exact(4)) {
                    let yuyv = [q[1], q[0], q[3], q[2]];
                    yuyv_to_rgb(&yuyv, 4, 2, 1, d);
                }
            }
            out.has_color = true;
        }
        _ => {
            // 3 or 4 bytes per pixel, RGB or BGR order.
            let bgr = enc.starts_with("bgr") || enc.starts_with("8uc");
            for r in 0..h {
                let line = rows(r);
                let dst = &mut out.rgb[3 * r * w..3 * (r + 1) * w];
                for (d, px) in dst.chunks_exact_mut(3).zip(line.chunks_exact(bpp)) {
                    if bgr {
                        d.copy_from_slice(&[px[2], px[1], px[0]]);
                    } else {
                        d.copy_from_slice(&px[..3]);
                    }
                }
            }
            out.has_color = true;
            gray_from_rgb(out);
        }
    }
    Ok(())
}

/// `sensor_msgs/CameraInfo`: what a calibration needs of it.
#[derive(Clone, Debug, PartialEq)]
pub struct CameraInfo {
    pub width: u32,
    pub height: u32,
    /// `plumb_bob`, `rational_polynomial`, `equidistant`, ...
    pub distortion_model: String,
    pub d: Vec<f64>,
    /// Row-major 3x3 intrinsics.
    pub k: [f64; 9],
    /// Row-major 3x4 projection.
    pub p: [f64; 12],
}

pub fn decode_camera_info(data: &[u8]) -> Result<CameraInfo, String> {
    let mut r = CdrReader::new(data).map_err(|e| e.to_string())?;
    let e = |e: super::cdr::CdrError| e.to_string();
    r.header().map_err(e)?;
    let height = r.u32("height").map_err(e)?;
    let width = r.u32("width").map_err(e)?;
    let distortion_model = r.string("distortion_model").map_err(e)?.to_string();
    let mut d = Vec::new();
    r.f64_seq("d", &mut d).map_err(e)?;
    let k = r.f64_array::<9>("k").map_err(e)?;
    let _r = r.f64_array::<9>("r").map_err(e)?;
    let p = r.f64_array::<12>("p").map_err(e)?;
    Ok(CameraInfo {
        width,
        height,
        distortion_model,
        d,
        k,
        p,
    })
}

/// A protobuf field's value (only the wire types these messages use).
enum Proto<'a> {
    Varint(u64),
    Fixed32(u32),
    Fixed64,
    Bytes(&'a [u8]),
}

/// Iterates over the fields of a protobuf message.
struct ProtoFields<'a>(&'a [u8]);

fn varint(b: &mut &[u8]) -> Result<u64, String> {
    let mut v = 0u64;
    for shift in (0..64).step_by(7) {
        let (&c, rest) = b.split_first().ok_or("truncated protobuf varint")?;
        *b = rest;
        v |= ((c & 0x7f) as u64) << shift;
        if c & 0x80 == 0 {
            return Ok(v);
        }
    }
    Err("protobuf varint longer than 10 bytes".into())
}

impl<'a> Iterator for ProtoFields<'a> {
    type Item = Result<(u64, Proto<'a>), String>;
    fn next(&mut self) -> Option<Self::Item> {
        if self.0.is_empty() {
            return None;
        }
        let r = (|| {
            let key = varint(&mut self.0)?;
            let (tag, wire) = (key >> 3, key & 7);
            let take = |b: &mut &'a [u8], n: usize| -> Result<&'a [u8], String> {
                if b.len() < n {
                    return Err(format!("protobuf field {tag} truncated"));
                }
                let (h, t) = b.split_at(n);
                *b = t;
                Ok(h)
            };
            let v = match wire {
                0 => Proto::Varint(varint(&mut self.0)?),
                1 => {
                    take(&mut self.0, 8)?;
                    Proto::Fixed64
                }
                2 => {
                    let n = varint(&mut self.0)?;
                    Proto::Bytes(take(&mut self.0, usize::try_from(n).unwrap_or(usize::MAX))?)
                }
                5 => {
                    let b = take(&mut self.0, 4)?;
                    Proto::Fixed32(u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
                }
                w => {
                    return Err(format!(
                        "protobuf wire type {w} (field {tag}) is not supported"
                    ))
                }
            };
            Ok((tag, v))
        })();
        if r.is_err() {
            self.0 = &[];
        }
        Some(r)
    }
}

/// `google.protobuf.Timestamp` (seconds, nanos) in seconds; `None` when zero.
fn proto_timestamp(b: &[u8]) -> Result<Option<f64>, String> {
    let (mut s, mut n) = (0i64, 0i64);
    for f in ProtoFields(b) {
        match f? {
            (1, Proto::Varint(v)) => s = v as i64,
            (2, Proto::Varint(v)) => n = v as i64,
            _ => {}
        }
    }
    Ok(nonzero(s as f64 + n as f64 * 1e-9))
}

#[cfg(test)]
mod tests {
    use super::super::cdr::CdrWriter;
    use super::*;
    use crate::decode::WideSamples;

    fn ros_image(enc: &str, w: u32, h: u32, step: u32, data: &[u8]) -> Vec<u8> {
        let mut c = CdrWriter::new();
        c.header(2_000_000_001, "cam");
        c.u32(h);
        c.u32(w);
        c.string(enc);
        c.u8(0);
        c.u32(step);
        c.bytes(data);
        c.as_bytes().to_vec()
    }

    #[test]
    fn ros_images_in_every_encoding_give_the_same_grey() -> Result<(), String> {
        let (w, h) = (4u32, 2u32);
        let rgb: Vec<u8> = (0..w * h * 3).map(|i| (i * 7 % 256) as u8).collect();
        let mut want = Frame::new(w, h);
        want.rgb.copy_from_slice(&rgb);
        gray_from_rgb(&mut want);
        let bgr: Vec<u8> = rgb.chunks(3).flat_map(|p| [p[2], p[1], p[0]]).collect();
        let rgba: Vec<u8> = rgb.chunks(3).flat_map(|p| [p[0], p[1], p[2], 9]).collect();
        // A padded row (step > width * 3) is read row by row.
        let mut padded = Vec::new();
        for r in rgb.chunks(12) {
            padded.extend_from_slice(r);
            padded.extend_from_slice(&[0; 4]);
        }
        for (enc, step, data) in [
            ("rgb8", 12, &rgb),
            ("bgr8", 12, &bgr),
            ("rgba8", 16, &rgba),
            ("rgb8", 16, &padded),
        ] {
            let msg = ros_image(enc, w, h, step, data);
            let m = decode_image(ImageSchema::RosImage, &msg).unwrap();
            assert!((m.stamp.unwrap() - 2.000000001).abs() < 1e-12);
            let ImagePayload::Raw {
                width,
                height,
                encoding,
                big_endian,
                step,
                data,
            } = m.payload
            else {
                panic!()
            };
            let mut f = Frame::new(0, 0);
            let wide = &mut WideSamples::default();
            raw_to_frame(
                width, height, encoding, big_endian, step, data, wide, &mut f,
            )?;
            assert_eq!(f.gray, want.gray, "{enc} step {step}");
            assert_eq!(f.rgb, want.rgb, "{enc}");
        }
        // Full-range mono16 keeps the high byte, 12-bit mono16 its 12 bits (either byte
        // order); YUYV and UYVY keep Y.
        let m16: Vec<u8> = [0x1234u16, 0xff00]
            .iter()
            .flat_map(|v| v.to_le_bytes())
            .collect();
        let mut f = Frame::new(0, 0);
        let wide = &mut WideSamples::default();
        raw_to_frame(2, 1, "mono16", false, 4, &m16, wide, &mut f)?;
        assert_eq!(f.gray, [0x12, 0xff]);
        let m12: Vec<u8> = [0x0800u16, 0x0fff]
            .iter()
            .flat_map(|v| v.to_be_bytes())
            .collect();
        let wide = &mut WideSamples::default();
        raw_to_frame(2, 1, "mono16", true, 4, &m12, wide, &mut f)?;
        assert_eq!(f.gray, [0x80, 0xff]);
        raw_to_frame(
            2,
            1,
            "yuv422_yuy2",
            false,
            4,
            &[10, 128, 20, 128],
            wide,
            &mut f,
        )?;
        assert_eq!(f.gray, [10, 20]);
        raw_to_frame(2, 1, "yuv422", false, 4, &[128, 10, 128, 20], wide, &mut f)?;
        assert_eq!(f.gray, [10, 20]);
        Ok(())
    }

    #[test]
    fn short_data_and_unknown_encodings_are_clear_errors() {
        let mut f = Frame::new(0, 0);
        let wide = &mut WideSamples::default();
        let e = raw_to_frame(4, 2, "rgb8", false, 12, &[0; 20], wide, &mut f).unwrap_err();
        assert!(
            e.contains("24 bytes") && e.contains("has step 12 and 20"),
            "{e}"
        );
        let e = raw_to_frame(4, 2, "bayer_rggb8", false, 4, &[0; 8], wide, &mut f).unwrap_err();
        assert!(e.contains("bayer_rggb8"), "{e}");
        let msg = ros_image("mono8", 4, 2, 4, &[0; 8]);
        for cut in 0..msg.len() {
            assert!(decode_image(ImageSchema::RosImage, &msg[..cut]).is_err());
        }
    }

    #[test]
    fn foxglove_protobuf_images_decode() {
        // foxglove.CompressedImage { timestamp { seconds: 3, nanos: 5 }, data: [1,2], format: "png" }
        let msg = [
            0x0a, 4, 0x08, 3, 0x10, 5, // timestamp
            0x12, 2, 1, 2, // data
            0x1a, 3, b'p', b'n', b'g', // format
            0x22, 1, b'c', // frame_id
        ];
        let m = decode_image(ImageSchema::FoxgloveCompressedImage, &msg).unwrap();
        assert!((m.stamp.unwrap() - 3.000000005).abs() < 1e-12);
        assert_eq!(
            m.payload,
            ImagePayload::Compressed {
                format: "png",
                data: &[1, 2]
            }
        );
        // foxglove.RawImage { width: 2, height: 1, encoding: "mono8", step: 2, data: [7, 8] }
        let mut raw = vec![0x15, 2, 0, 0, 0, 0x1d, 1, 0, 0, 0, 0x22, 5];
        raw.extend_from_slice(b"mono8");
        raw.extend_from_slice(&[0x2d, 2, 0, 0, 0, 0x32, 2, 7, 8]);
        let m = decode_image(ImageSchema::FoxgloveRawImage, &raw).unwrap();
        assert_eq!(m.stamp, None);
        assert!(matches!(
            m.payload,
            ImagePayload::Raw {
                width: 2,
                height: 1,
                encoding: "mono8",
                step: 2,
                data: [7, 8],
                ..
            }
        ));
        assert!(decode_image(ImageSchema::FoxgloveRawImage, &raw[..raw.len() - 1]).is_err());
        assert!(ImageSchema::of("foxglove.RawImage", "json")
            .unwrap()
            .is_err());
        assert_eq!(
            ImageSchema::of("sensor_msgs/msg/Image", "cdr"),
            Some(Ok(ImageSchema::RosImage))
        );
    }

    #[test]
    fn camera_info_round_trip() {
        let mut c = CdrWriter::new();
        c.header(0, "cam");
        c.u32(480);
        c.u32(640);
        c.string("plumb_bob");
        c.u32(5);
        for v in [0.1, -0.2, 0.001, 0.002, 0.0] {
            c.f64(v);
        }
        for v in [500.0, 0.0, 320.0, 0.0, 501.0, 240.0, 0.0, 0.0, 1.0] {
            c.f64(v);
        }
        for _ in 0..21 {
            c.f64(0.0);
        }
        let info = decode_camera_info(c.as_bytes()).unwrap();
        assert_eq!((info.width, info.height), (640, 480));
        assert_eq!(info.distortion_model, "plumb_bob");
        assert_eq!(info.d, [0.1, -0.2, 0.001, 0.002, 0.0]);
        assert_eq!(info.k[4], 501.0);
    }
}
