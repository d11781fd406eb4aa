//! Device buffers into the preallocated [`Frame`]: GREY copied, YUYV's Y bytes taken as grey
//! (colour by BT.601 when wanted), MJPEG decoded into reused buffers, with the standard Huffman
//! tables put back when the camera leaves them out (as many UVC webcams do).

use std::path::Path;

use super::format::PixelFormat;
use crate::decode::ImageDecoderBuf;
use crate::{Frame, SourceError};

/// Converts one pixel format into frames; keeps its scratch buffers between frames.
pub struct Converter {
    format: PixelFormat,
    width: u32,
    height: u32,
    /// Bytes per row in the device buffer (>= the packed row size).
    stride: usize,
    colour: bool,
    jpeg: ImageDecoderBuf,
    jpeg_fixed: Vec<u8>,
    name: String,
}

impl Converter {
    /// `stride` 0 means packed rows. With `colour` set, YUYV and MJPEG also fill `Frame::rgb`.
    pub fn new(
        name: &str,
        format: PixelFormat,
        width: u32,
        height: u32,
        stride: usize,
        colour: bool,
    ) -> Self {
        let packed = match format {
            PixelFormat::Yuyv => width as usize * 2,
            _ => width as usize,
        };
        Converter {
            format,
            width,
            height,
            stride: stride.max(packed),
            colour,
            jpeg: ImageDecoderBuf::new(),
            jpeg_fixed: Vec::with_capacity(width as usize * height as usize),
            name: name.to_string(),
        }
    }

    /// Fills `out` from a device buffer. A short or undecodable buffer (a glitch on the wire) is
    /// a frame-local [`SourceError::Decode`]: the caller skips the frame and goes on.
    pub fn convert(&mut self, data: &[u8], out: &mut Frame) -> Result<(), SourceError> {
        out.ensure_size(self.width, self.height);
        let (w, h) = (self.width as usize, self.height as usize);
        let need = match self.format {
            PixelFormat::Grey => self.stride * (h - 1) + w,
            PixelFormat::Yuyv => self.stride * (h - 1) + 2 * w,
            _ => 0,
        };
        if data.len() < need {
            return Err(self.decode_error(format!(
                "short buffer: {} bytes, {} expected",
                data.len(),
                need
            )));
        }
        match self.format {
            PixelFormat::Grey => {
                grey_rows(data, self.stride, w, h, &mut out.gray);
                out.has_color = false;
            }
            PixelFormat::Yuyv => {
                yuyv_to_grey(data, self.stride, w, h, &mut out.gray);
                out.has_color = self.colour;
                if self.colour {
                    yuyv_to_rgb(data, self.stride, w, h, &mut out.rgb);
                }
            }
            PixelFormat::Mjpeg => {
                let bytes = if needs_huffman_tables(data) {
                    insert_standard_huffman_tables(data, &mut self.jpeg_fixed);
                    &self.jpeg_fixed[..]
                } else {
                    data
                };
                self.jpeg.decode(
                    bytes,
                    Path::new(&self.name),
                    Some((self.width, self.height)),
                    out,
                )?;
                if !self.colour {
                    out.has_color = false;
                }
            }
            PixelFormat::Other(_) => {
                return Err(
                    self.decode_error(format!("pixel format {} cannot be converted", self.format))
                )
            }
        }
        Ok(())
    }

    fn decode_error(&self, message: String) -> SourceError {
        SourceError::Decode {
            path: self.name.clone().into(),
            message,
        }
    }
}

/// Copies `h` rows of `w` bytes from a buffer with `stride` bytes per row.
pub fn grey_rows(src: &[u8], stride: usize, w: usize, h: usize, out: &mut [u8]) {
    for (row, dst) in out.chunks_exact_mut(w).take(h).enumerate() {
        dst.copy_from_slice(&src[row * stride..row * stride + w]);
    }
}

/// YUYV (Y0 U Y1 V per two pixels): the Y bytes are the grey image.
pub fn yuyv_to_grey(src: &[u8], stride: usize, w: usize, h: usize, out: &mut [u8]) {
    for (row, dst) in out.chunks_exact_mut(w).take(h).enumerate() {
        let line = &src[row * stride..row * stride + 2 * w];
        for (d, px) in dst.iter_mut().zip(line.chunks_exact(2)) {
            *d = px[0];
        }
    }
}

/// YUYV to RGB with the BT.601 limited-range matrix in integer arithmetic.
pub fn yuyv_to_rgb(src: &[u8], stride: usize, w: usize, h: usize, out: &mut [u8]) {
    for (row, dst) in out.chunks_exact_mut(3 * w).take(h).enumerate() {
        let line = &src[row * stride..row * stride + 2 * w];
        for (d, q) in dst.chunks_exact_mut(6).zip(line.chunks_exact(4)) {
            let (u, v) = (q[1] as i32 - 128, q[3] as i32 - 128);
            for (k, y) in [q[0], q[2]].into_iter().enumerate() {
                let c = 298 * (y as i32 - 16);
                d[3 * k] = clamp8((c + 409 * v + 128) >> 8);
                d[3 * k + 1] = clamp8((c - 100 * u - 208 * v + 128) >> 8);
                d[3 * k + 2] = clamp8((c + 516 * u + 128) >> 8);
            }
        }
    }
}

#[inline]
fn clamp8(v: i32) -> u8 {
    v.clamp(0, 255) as u8
}

/// True when a JPEG has no DHT segment before its first scan (UVC MJPEG often omits them).
pub fn needs_huffman_tables(jpeg: &[u8]) -> bool {
    let mut i = 2;
    if jpeg.len() < 4 || jpeg[0] != 0xFF || jpeg[1] != 0xD8 {
        return false; // not a JPEG: let the decoder say so
    }
    while i + 4 <= jpeg.len() {
        if jpeg[i] != 0xFF {
            return false;
        }
        let marker = jpeg[i + 1];
        match marker {
            0xC4 => return false,
            0xDA => return true,
            0xD8 | 0x01 | 0xD0..=0xD7 => i += 2,
            0xFF => i += 1,
            _ => {
                let len = u16::from_be_bytes([jpeg[i + 2], jpeg[i + 3]]) as usize;
                i += 2 + len;
            }
        }
    }
    false
}

/// Writes `jpeg` into `out` with the standard tables of ITU-T T.81 Annex K.3 inserted right
/// after SOI (what every MJPEG decoder assumes for such streams).
pub fn insert_standard_huffman_tables(jpeg: &[u8], out: &mut Vec<u8>) {
    out.clear();
    out.extend_from_slice(&jpeg[..2]);
    let tables: [(u8, &[u8; 16], &[u8]); 4] = [
        (0x00, &DC_LUMA_BITS, &DC_VALUES),
        (0x10, &AC_LUMA_BITS, &AC_LUMA_VALUES),
        (0x01, &DC_CHROMA_BITS, &DC_VALUES),
        (0x11, &AC_CHROMA_BITS, &AC_CHROMA_VALUES),
    ];
    let len: usize = 2 + tables.iter().map(|t| 17 + t.2.len()).sum::<usize>();
    out.extend_from_slice(&[0xFF, 0xC4]);
    out.extend_from_slice(&(len as u16).to_be_bytes());
    for (class_id, bits, values) in tables {
        out.push(class_id);
        out.extend_from_slice(bits);
        out.extend_from_slice(values);
    }
    out.extend_from_slice(&jpeg[2..]);
}

const DC_LUMA_BITS: [u8; 16] = [0, 1, 5, 1, 1, 1, 1, 1, 1, 0, 0, 0, 0, 0, 0, 0];
const DC_CHROMA_BITS: [u8; 16] = [0, 3, 1, 1, 1, 1, 1, 1, 1, 1, 1, 0, 0, 0, 0, 0];
const DC_VALUES: [u8; 12] = [0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11];
const AC_LUMA_BITS: [u8; 16] = [0, 2, 1, 3, 3, 2, 4, 3, 5, 5, 4, 4, 0, 0, 1, 0x7d];
const AC_CHROMA_BITS: [u8; 16] = [0, 2, 1, 2, 4, 4, 3, 4, 7, 5, 4, 4, 0, 1, 2, 0x77];
#[rustfmt::skip]
const AC_LUMA_VALUES: [u8; 162] = [
    0x01, 0x02, 0x03, 0x00, 0x04, 0x11, 0x05, 0x12, 0x21, 0x31, 0x41, 0x06, 0x13, 0x51, 0x61, 0x07,
    0x22, 0x71, 0x14, 0x32, 0x81, 0x91, 0xa1, 0x08, 0x23, 0x42, 0xb1, 0xc1, 0x15, 0x52, 0xd1, 0xf0,
    0x24, 0x33, 0x62, 0x72, 0x82, 0x09, 0x0a, 0x16, 0x17, 0x18, 0x19, 0x1a, 0x25, 0x26, 0x27, 0x28,
    0x29, 0x2a, 0x34, 0x35, 0x36, 0x37, 0x38, 0x39, 0x3a, 0x43, 0x44, 0x45, 0x46, 0x47, 0x48, 0x49,
    0x4a, 0x53, 0x54, 0x55, 0x56, 0x57, 0x58, 0x59, 0x5a, 0x63, 0x64, 0x65, 0x66, 0x67, 0x68, 0x69,
    0x6a, 0x73, 0x74, 0x75, 0x76, 0x77, 0x78, 0x79, 0x7a, 0x83, 0x84, 0x85, 0x86, 0x87, 0x88, 0x89,
    0x8a, 0x92, 0x93, 0x94, 0x95, 0x96, 0x97, 0x98, 0x99, 0x9a, 0xa2, 0xa3, 0xa4, 0xa5, 0xa6, 0xa7,
    0xa8, 0xa9, 0xaa, 0xb2, 0xb3, 0xb4, 0xb5, 0xb6, 0xb7, 0xb8, 0xb9, 0xba, 0xc2, 0xc3, 0xc4, 0xc5,
    0xc6, 0xc7, 0xc8, 0xc9, 0xca, 0xd2, 0xd3, 0xd4, 0xd5, 0xd6, 0xd7, 0xd8, 0xd9, 0xda, 0xe1, 0xe2,
    0xe3, 0xe4, 0xe5, 0xe6, 0xe7, 0xe8, 0xe9, 0xea, 0xf1, 0xf2, 0xf3, 0xf4, 0xf5, 0xf6, 0xf7, 0xf8,
    0xf9, 0xfa,
];
#[rustfmt::skip]
const AC_CHROMA_VALUES: [u8; 162] = [
    0x00, 0x01, 0x02, 0x03, 0x11, 0x04, 0x05, 0x21, 0x31, 0x06, 0x12, 0x41, 0x51, 0x07, 0x61, 0x71,
    0x13, 0x22, 0x32, 0x81, 0x08, 0x14, 0x42, 0x91, 0xa1, 0xb1, 0xc1, 0x09, 0x23, 0x33, 0x52, 0xf0,
    0x15, 0x62, 0x72, 0xd1, 0x0a, 0x16, 0x24, 0x34, 0xe1, 0x25, 0xf1, 0x17, 0x18, 0x19, 0x1a, 0x26,
    0x27, 0x28, 0x29, 0x2a, 0x35, 0x36, 0x37, 0x38, 0x39, 0x3a, 0x43, 0x44, 0x45, 0x46, 0x47, 0x48,
    0x49, 0x4a, 0x53, 0x54, 0x55, 0x56, 0x57, 0x58, 0x59, 0x5a, 0x63, 0x64, 0x65, 0x66, 0x67, 0x68,
    0x69, 0x6a, 0x73, 0x74, 0x75, 0x76, 0x77, 0x78, 0x79, 0x7a, 0x82, 0x83, 0x84, 0x85, 0x86, 0x87,
    0x88, 0x89, 0x8a, 0x92, 0x93, 0x94, 0x95, 0x96, 0x97, 0x98, 0x99, 0x9a, 0xa2, 0xa3, 0xa4, 0xa5,
    0xa6, 0xa7, 0xa8, 0xa9, 0xaa, 0xb2, 0xb3, 0xb4, 0xb5, 0xb6, 0xb7, 0xb8, 0xb9, 0xba, 0xc2, 0xc3,
    0xc4, 0xc5, 0xc6, 0xc7, 0xc8, 0xc9, 0xca, 0xd2, 0xd3, 0xd4, 0xd5, 0xd6, 0xd7, 0xd8, 0xd9, 0xda,
    0xe2, 0xe3, 0xe4, 0xe5, 0xe6, 0xe7, 0xe8, 0xe9, 0xea, 0xf2, 0xf3, 0xf4, 0xf5, 0xf6, 0xf7, 0xf8,
    0xf9, 0xfa,
];

/// Encoders for tests and the fake device: the inverse conversions.
pub mod encode {
    /// Grey + RGB into YUYV (BT.601 limited range), `stride` bytes per row.
    pub fn yuyv_from_rgb(rgb: &[u8], w: usize, h: usize, stride: usize, out: &mut Vec<u8>) {
        out.clear();
        out.resize(stride * h, 0);
        for y in 0..h {
            for x in (0..w).step_by(2) {
                let px = |k: usize| {
                    let i = 3 * (y * w + (x + k).min(w - 1));
                    (rgb[i] as i32, rgb[i + 1] as i32, rgb[i + 2] as i32)
                };
                let luma =
                    |(r, g, b): (i32, i32, i32)| ((66 * r + 129 * g + 25 * b + 128) >> 8) + 16;
                let (p0, p1) = (px(0), px(1));
                let (r, g, b) = ((p0.0 + p1.0) / 2, (p0.1 + p1.1) / 2, (p0.2 + p1.2) / 2);
                let u = ((-38 * r - 74 * g + 112 * b + 128) >> 8) + 128;
                let v = ((112 * r - 94 * g - 18 * b + 128) >> 8) + 128;
                let o = y * stride + 2 * x;
                out[o] = luma(p0).clamp(0, 255) as u8;
                out[o + 1] = u.clamp(0, 255) as u8;
                out[o + 2] = luma(p1).clamp(0, 255) as u8;
                out[o + 3] = v.clamp(0, 255) as u8;
            }
        }
    }

    /// A JPEG of an RGB image (quality 90), as an MJPEG camera would send it.
    pub fn jpeg_from_rgb(rgb: &[u8], w: u32, h: u32, out: &mut Vec<u8>) -> Result<(), String> {
        out.clear();
        let enc = image::codecs::jpeg::JpegEncoder::new_with_quality(&mut *out, 90);
        image::ImageEncoder::write_image(enc, rgb, w, h, image::ExtendedColorType::Rgb8)
            .map_err(|e| e.to_string())
    }

    /// Removes every DHT segment, as UVC cameras send MJPEG.
    pub fn strip_huffman_tables(jpeg: &[u8]) -> Vec<u8> {
        let mut out = jpeg[..2].to_vec();
        let mut i = 2;
        while i + 4 <= jpeg.len() && jpeg[i] == 0xFF && jpeg[i + 1] != 0xDA {
            let len = u16::from_be_bytes([jpeg[i + 2], jpeg[i + 3]]) as usize;
            if jpeg[i + 1] != 0xC4 {
                out.extend_from_slice(&jpeg[i..i + 2 + len]);
            }
            i += 2 + len;
        }
        out.extend_from_slice(&jpeg[i..]);
        out
    }
}

#[cfg(test)]
mod tests {
    use super::encode::*;
    use super::*;

    fn test_rgb(w: usize, h: usize) -> Vec<u8> {
        (0..w * h)
            .flat_map(|i| {
                let (x, y) = (i % w, i / w);
                [(x * 4) as u8, (y * 5) as u8, ((x + y) * 3) as u8]
            })
            .collect()
    }

    #[test]
    fn grey_with_row_padding() {
        let (w, h, stride) = (5, 3, 8);
        let src: Vec<u8> = (0..stride * h).map(|i| i as u8).collect();
        let mut c = Converter::new("cam", PixelFormat::Grey, w as u32, h as u32, stride, false);
        let mut f = Frame::new(w as u32, h as u32);
        c.convert(&src, &mut f).unwrap();
        assert_eq!(&f.gray[5..10], &[8, 9, 10, 11, 12]);
        assert!(!f.has_color);
    }

    #[test]
    fn yuyv_round_trip_is_close_in_grey_and_colour() {
        let (w, h) = (32, 8);
        let rgb = test_rgb(w, h);
        let mut yuyv = Vec::new();
        yuyv_from_rgb(&rgb, w, h, 2 * w + 16, &mut yuyv);
        let mut c = Converter::new(
            "cam",
            PixelFormat::Yuyv,
            w as u32,
            h as u32,
            2 * w + 16,
            true,
        );
        let mut f = Frame::new(w as u32, h as u32);
        c.convert(&yuyv, &mut f).unwrap();
        assert!(f.has_color);
        for i in 0..w * h {
            // Limited-range Y: grey is 16 + 219/255 of the full-range luma.
            let l = crate::frame::luma(rgb[3 * i], rgb[3 * i + 1], rgb[3 * i + 2]) as f64;
            assert!((f.gray[i] as f64 - (16.0 + l * 219.0 / 255.0)).abs() <= 2.0);
        }
        // Colour error comes from 4:2:2 chroma: small on this smooth image.
        let err: f64 = rgb
            .iter()
            .zip(&f.rgb)
            .map(|(a, b)| (*a as f64 - *b as f64).abs())
            .sum::<f64>()
            / rgb.len() as f64;
        assert!(err < 4.0, "mean colour error {err}");
    }

    #[test]
    fn short_buffers_are_frame_local_errors() {
        let mut c = Converter::new("/dev/video0", PixelFormat::Yuyv, 16, 4, 0, false);
        let mut f = Frame::new(16, 4);
        let e = c.convert(&[0; 100], &mut f).unwrap_err();
        assert!(e.is_frame_local());
        assert!(
            e.to_string().contains("/dev/video0") && e.to_string().contains("short buffer"),
            "{e}"
        );
    }

    #[test]
    fn mjpeg_without_huffman_tables_decodes_like_the_original() {
        let (w, h) = (64, 48);
        let rgb = test_rgb(w, h);
        let mut jpeg = Vec::new();
        jpeg_from_rgb(&rgb, w as u32, h as u32, &mut jpeg).unwrap();
        assert!(!needs_huffman_tables(&jpeg));
        let stripped = strip_huffman_tables(&jpeg);
        assert!(stripped.len() < jpeg.len());
        assert!(needs_huffman_tables(&stripped));
        let mut c = Converter::new("cam", PixelFormat::Mjpeg, w as u32, h as u32, 0, true);
        let (mut a, mut b) = (
            Frame::new(w as u32, h as u32),
            Frame::new(w as u32, h as u32),
        );
        c.convert(&jpeg, &mut a).unwrap();
        c.convert(&stripped, &mut b).unwrap();
        assert_eq!(a.gray, b.gray);
        assert_eq!(a.rgb, b.rgb);
        assert!(a.has_color);
    }

    #[test]
    fn corrupt_mjpeg_is_a_frame_local_error() {
        let mut c = Converter::new("cam", PixelFormat::Mjpeg, 64, 48, 0, false);
        let mut f = Frame::new(64, 48);
        let e = c
            .convert(&[0xFF, 0xD8, 0xFF, 0xDB, 0, 4, 1, 2], &mut f)
            .unwrap_err();
        assert!(e.is_frame_local(), "{e}");
    }

    #[test]
    fn standard_tables_have_the_published_sizes() {
        let sum = |b: &[u8; 16]| b.iter().map(|&x| x as usize).sum::<usize>();
        assert_eq!(sum(&DC_LUMA_BITS), DC_VALUES.len());
        assert_eq!(sum(&DC_CHROMA_BITS), DC_VALUES.len());
        assert_eq!(sum(&AC_LUMA_BITS), AC_LUMA_VALUES.len());
        assert_eq!(sum(&AC_CHROMA_BITS), AC_CHROMA_VALUES.len());
    }
}
