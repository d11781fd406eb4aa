//! Image decoding into reused frame buffers (PNG and JPEG).

use std::io::Cursor;
use std::path::Path;

use image::{ColorType, ImageDecoder, ImageReader};

use crate::frame::{gray_from_rgb, luma};
use crate::{Frame, SourceError};

/// Largest image accepted (8K video is 33 Mpixel): a corrupt header cannot make sdslam allocate
/// gigabytes.
pub const MAX_PIXELS: u64 = 64_000_000;

/// Decodes encoded images into a [`Frame`], keeping its scratch buffers between calls.
#[derive(Default)]
pub struct ImageDecoderBuf {
    bytes: Vec<u8>,
    scratch: Vec<u8>,
    wide: WideSamples,
}

/// How one source's 16-bit samples become 8-bit grey levels. Their significant bits are often
/// fewer than 16: machine-vision and thermal cameras write 10, 12 or 14 bits (and some tools 8)
/// into 16-bit PNGs and ROS `mono16` messages. Keeping the high byte turns a 12-bit image into
/// grey levels 0-15, on which nothing is tracked. The right shift is that of the smallest
/// common depth holding the largest sample of the first image with content (largest sample
/// at least `MIN_WIDE_CONTENT`, 64), then kept for the source so brightness never jumps between
/// frames; brighter samples later saturate.
#[derive(Clone, Copy, Debug, Default)]
pub struct WideSamples {
    shift: Option<u32>,
}

/// Largest 16-bit sample below which an image is too dark to tell its bit depth.
const MIN_WIDE_CONTENT: u16 = 64;

impl WideSamples {
    /// The shift for an image whose largest (colour) sample `max` gives; `max` is only
    /// computed while the depth is undecided (a scan of the whole image).
    pub fn shift(&mut self, max: impl FnOnce() -> u16) -> u32 {
        if self.shift.is_none() {
            self.shift = match max() {
                m if m < MIN_WIDE_CONTENT => None,
                0..=255 => Some(0),
                256..=1023 => Some(2),
                1024..=4095 => Some(4),
                4096..=16383 => Some(6),
                _ => Some(8),
            };
        }
        self.shift.unwrap_or(8)
    }

    /// `v` as an 8-bit grey level.
    #[inline]
    pub fn to_u8(shift: u32, v: u16) -> u8 {
        (v >> shift).min(255) as u8
    }
}

impl ImageDecoderBuf {
    pub fn new() -> Self {
        Self::default()
    }

    /// The source's 16-bit depth, for raw pixels decoded beside the encoded ones.
    pub fn wide_samples(&mut self) -> &mut WideSamples {
        &mut self.wide
    }

    /// Reads `path` and decodes it into `out`. With `expect` set, an image of another size is
    /// an error (the calibration fixes the size).
    pub fn read_file(
        &mut self,
        path: &Path,
        expect: Option<(u32, u32)>,
        out: &mut Frame,
    ) -> Result<(), SourceError> {
        use std::io::Read;
        self.bytes.clear();
        let f = std::fs::File::open(path).map_err(|e| SourceError::io(path, e))?;
        let cap = max_file_bytes(expect);
        f.take(cap + 1)
            .read_to_end(&mut self.bytes)
            .map_err(|e| SourceError::io(path, e))?;
        if self.bytes.len() as u64 > cap {
            self.bytes = Vec::new();
            return Err(SourceError::Decode {
                path: path.to_path_buf(),
                message: format!(
                    "file is larger than {cap} bytes, more than any encoding of an image of this size"
                ),
            });
        }
        let bytes = std::mem::take(&mut self.bytes);
        let r = self.decode(&bytes, path, expect, out);
        self.bytes = bytes;
        r
    }

    /// Decodes an in-memory encoded image; `path` only names it in errors.
    pub fn decode(
        &mut self,
        bytes: &[u8],
        path: &Path,
        expect: Option<(u32, u32)>,
        out: &mut Frame,
    ) -> Result<(), SourceError> {
        let derr = |m: String| SourceError::Decode {
            path: path.to_path_buf(),
            message: m,
        };
        if bytes.is_empty() {
            return Err(derr("file is empty".into()));
        }
        let reader = ImageReader::new(Cursor::new(bytes))
            .with_guessed_format()
            .map_err(|e| derr(e.to_string()))?;
        if reader.format().is_none() {
            return Err(derr("unknown image format (PNG or JPEG expected)".into()));
        }
        if reader.format() == Some(image::ImageFormat::Jpeg) && !jpeg_is_complete(bytes) {
            return Err(derr(
                "truncated JPEG (no end-of-image marker after the scan)".into(),
            ));
        }
        let dec = reader.into_decoder().map_err(|e| derr(e.to_string()))?;
        let (w, h) = dec.dimensions();
        if w == 0 || h == 0 {
            return Err(derr(format!("image has zero size {w}x{h}")));
        }
        // A corrupt header can claim any size: refuse before allocating for it.
        if w as u64 * h as u64 > MAX_PIXELS {
            return Err(derr(format!(
                "image claims {w}x{h} pixels, more than the {MAX_PIXELS} sdslam accepts"
            )));
        }
        if let Some((ew, eh)) = expect {
            if (w, h) != (ew, eh) {
                return Err(SourceError::Size {
                    path: path.to_path_buf(),
                    got_w: w,
                    got_h: h,
                    want_w: ew,
                    want_h: eh,
                });
            }
        }
        out.ensure_size(w, h);
        let color = dec.color_type();
        let total = dec.total_bytes() as usize;
        match color {
            ColorType::L8 => {
                dec.read_image(&mut out.gray)
                    .map_err(|e| derr(e.to_string()))?;
                out.has_color = false;
            }
            ColorType::Rgb8 => {
                dec.read_image(&mut out.rgb)
                    .map_err(|e| derr(e.to_string()))?;
                out.has_color = true;
                gray_from_rgb(out);
            }
            ColorType::La8
            | ColorType::Rgba8
            | ColorType::L16
            | ColorType::Rgb16
            | ColorType::Rgba16
            | ColorType::La16 => {
                self.scratch.resize(total, 0);
                dec.read_image(&mut self.scratch)
                    .map_err(|e| derr(e.to_string()))?;
                let shift = if bytes_per_sample(color) == 2 {
                    let scratch = &self.scratch;
                    self.wide.shift(|| max_colour_sample(color, scratch))
                } else {
                    0
                };
                convert_other(color, &self.scratch, shift, out);
            }
            other => return Err(derr(format!("unsupported pixel type {other:?}"))),
        }
        Ok(())
    }
}

/// Largest image file read: an uncompressed 16-bit RGBA encoding of the expected size (or of
/// [`MAX_PIXELS`]) plus room for metadata; a padded or endless file is refused unread.
fn max_file_bytes(expect: Option<(u32, u32)>) -> u64 {
    let pixels = expect.map_or(MAX_PIXELS, |(w, h)| w as u64 * h as u64);
    pixels.min(MAX_PIXELS) * 8 + (16 << 20)
}

/// True when the last scan (SOS marker `FF DA`) is followed by the end-of-image marker
/// `FF D9`. Entropy-coded data stuffs every `FF` with `00`, so neither marker appears inside
/// it; an EXIF thumbnail's own markers come before the main image's scan. A file cut short
/// (a partial write, a dropped USB transfer) has no EOI after its scan: the decoder would
/// fill the rest with grey and features would be tracked on it.
fn jpeg_is_complete(bytes: &[u8]) -> bool {
    let last = |m: u8| bytes.windows(2).rposition(|w| w[0] == 0xFF && w[1] == m);
    match (last(0xDA), last(0xD9)) {
        (Some(sos), Some(eoi)) => eoi > sos,
        _ => false,
    }
}

fn bytes_per_sample(color: ColorType) -> usize {
    color.bytes_per_pixel() as usize / color.channel_count() as usize
}

/// The largest colour sample (alpha left out) of 16-bit native-endian pixels.
fn max_colour_sample(color: ColorType, src: &[u8]) -> u16 {
    let chans = color.channel_count() as usize;
    let colours = if color.has_alpha() { chans - 1 } else { chans };
    src.chunks_exact(2 * chans)
        .flat_map(|px| {
            px.chunks_exact(2)
                .take(colours)
                .map(|b| u16::from_ne_bytes([b[0], b[1]]))
        })
        .max()
        .unwrap_or(0)
}

/// Converts the less common layouts (alpha, 16-bit) into grey + RGB; 16-bit samples are
/// shifted right by `shift` and saturated.
fn convert_other(color: ColorType, src: &[u8], shift: u32, out: &mut Frame) {
    let chans = color.channel_count() as usize;
    let wide = bytes_per_sample(color) == 2;
    let sample = |px: &[u8], c: usize| -> u8 {
        if wide {
            // 16-bit samples are native-endian in the decoder output.
            WideSamples::to_u8(shift, u16::from_ne_bytes([px[2 * c], px[2 * c + 1]]))
        } else {
            px[c]
        }
    };
    let bpp = color.bytes_per_pixel() as usize;
    let is_color = chans >= 3;
    out.has_color = is_color;
    for (i, px) in src.chunks_exact(bpp).enumerate() {
        if is_color {
            let (r, g, b) = (sample(px, 0), sample(px, 1), sample(px, 2));
            out.rgb[3 * i] = r;
            out.rgb[3 * i + 1] = g;
            out.rgb[3 * i + 2] = b;
            out.gray[i] = luma(r, g, b);
        } else {
            out.gray[i] = sample(px, 0);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn encode_png_gray(w: u32, h: u32) -> Vec<u8> {
        let img = image::GrayImage::from_fn(w, h, |x, y| image::Luma([(x * 10 + y) as u8]));
        let mut v = Vec::new();
        img.write_to(&mut Cursor::new(&mut v), image::ImageFormat::Png)
            .unwrap();
        v
    }

    #[test]
    fn decodes_gray_png_into_reused_frame() {
        let bytes = encode_png_gray(8, 4);
        let mut d = ImageDecoderBuf::new();
        let mut f = Frame::new(8, 4);
        let ptr = f.gray.as_ptr();
        d.decode(&bytes, Path::new("a.png"), Some((8, 4)), &mut f)
            .unwrap();
        assert_eq!(f.gray_at(3, 2), 32);
        assert!(!f.has_color);
        assert_eq!(ptr, f.gray.as_ptr());
    }

    #[test]
    fn decodes_rgb_jpeg_to_gray_and_color() {
        let img = image::RgbImage::from_fn(16, 16, |_, _| image::Rgb([200, 100, 50]));
        let mut v = Vec::new();
        img.write_to(&mut Cursor::new(&mut v), image::ImageFormat::Jpeg)
            .unwrap();
        let mut f = Frame::new(16, 16);
        ImageDecoderBuf::new()
            .decode(&v, Path::new("a.jpg"), None, &mut f)
            .unwrap();
        assert!(f.has_color);
        let g = f.gray_at(5, 5) as i32;
        assert!((g - luma(200, 100, 50) as i32).abs() <= 3, "{g}");
    }

    #[test]
    fn rejects_headers_claiming_a_huge_image() {
        // A valid 1x1 PNG whose IHDR claims 60000x60000 (the CRC is not checked before the
        // size is read by every decoder, so fix it up to be sure the size check is what fails).
        let mut png = encode_png_gray(1, 1);
        png[16..20].copy_from_slice(&60000u32.to_be_bytes());
        png[20..24].copy_from_slice(&60000u32.to_be_bytes());
        let crc = crc32(&png[12..29]);
        png[29..33].copy_from_slice(&crc.to_be_bytes());
        let mut f = Frame::new(1, 1);
        let e = ImageDecoderBuf::new()
            .decode(&png, Path::new("big.png"), None, &mut f)
            .unwrap_err();
        assert!(e.to_string().contains("60000x60000"), "{e}");
        assert_eq!(f.gray.len(), 1, "nothing was allocated for it");
    }

    fn crc32(bytes: &[u8]) -> u32 {
        let mut c = 0xFFFF_FFFFu32;
        for &b in bytes {
            c ^= b as u32;
            for _ in 0..8 {
                c = if c & 1 != 0 {
                    0xEDB8_8320 ^ (c >> 1)
                } else {
                    c >> 1
                };
            }
        }
        !c
    }

    #[test]
    fn rejects_a_truncated_jpeg_and_accepts_trailing_padding() {
        let img =
            image::RgbImage::from_fn(64, 48, |x, y| image::Rgb([(x * 4) as u8, (y * 5) as u8, 7]));
        let mut jpg = Vec::new();
        image::codecs::jpeg::JpegEncoder::new_with_quality(&mut jpg, 90)
            .encode_image(&img)
            .unwrap();
        let mut d = ImageDecoderBuf::new();
        let mut f = Frame::new(64, 48);
        d.decode(&jpg, Path::new("a.jpg"), None, &mut f).unwrap();
        for cut in [jpg.len() / 3, jpg.len() - 2] {
            let e = d
                .decode(&jpg[..cut], Path::new("t.jpg"), None, &mut f)
                .unwrap_err()
                .to_string();
            assert!(e.contains("t.jpg") && e.contains("truncated"), "{e}");
        }
        let mut padded = jpg.clone();
        padded.extend_from_slice(&[0; 100]);
        d.decode(&padded, Path::new("p.jpg"), None, &mut f).unwrap();
    }

    #[test]
    fn refuses_a_padded_file_without_reading_it_whole() {
        let dir = std::env::temp_dir().join(format!("sdslam-decode-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let p = dir.join("big.png");
        let mut bytes = encode_png_gray(8, 4);
        bytes.resize(20 << 20, 0);
        std::fs::write(&p, &bytes).unwrap();
        let mut f = Frame::new(8, 4);
        let e = ImageDecoderBuf::new()
            .read_file(&p, Some((8, 4)), &mut f)
            .unwrap_err()
            .to_string();
        assert!(e.contains("big.png") && e.contains("larger than"), "{e}");
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn rejects_wrong_size_corrupt_truncated_and_empty() {
        let bytes = encode_png_gray(8, 4);
        let mut d = ImageDecoderBuf::new();
        let mut f = Frame::new(8, 4);
        let e = d
            .decode(&bytes, Path::new("a.png"), Some((640, 480)), &mut f)
            .unwrap_err();
        assert!(e.to_string().contains("expected 640x480"), "{e}");
        let e = d.decode(&[], Path::new("z.png"), None, &mut f).unwrap_err();
        assert!(e.to_string().contains("z.png") && e.to_string().contains("empty"));
        let e = d
            .decode(b"not an image at all", Path::new("c.png"), None, &mut f)
            .unwrap_err();
        assert!(e.to_string().contains("c.png"), "{e}");
        let e = d
            .decode(&bytes[..bytes.len() / 2], Path::new("t.png"), None, &mut f)
            .unwrap_err();
        assert!(e.to_string().contains("t.png"), "{e}");
    }

    type TestResult<T> = Result<T, Box<dyn std::error::Error>>;

    fn encode_png_gray16(w: u32, h: u32, value: impl Fn(u32, u32) -> u16) -> TestResult<Vec<u8>> {
        let img = image::ImageBuffer::<image::Luma<u16>, Vec<u16>>::from_fn(w, h, |x, y| {
            image::Luma([value(x, y)])
        });
        let mut v = Vec::new();
        img.write_to(&mut Cursor::new(&mut v), image::ImageFormat::Png)?;
        Ok(v)
    }

    #[test]
    fn sixteen_bit_images_use_their_significant_bits() -> TestResult<()> {
        let decode = |d: &mut ImageDecoderBuf, bytes: &[u8]| -> TestResult<Frame> {
            let mut f = Frame::new(16, 16);
            d.decode(bytes, Path::new("a.png"), None, &mut f)?;
            Ok(f)
        };
        // 12 bits in 16 (a machine-vision camera): the full grey range, not levels 0-15.
        let twelve = encode_png_gray16(16, 16, |x, y| ((x * 16 + y) * 16) as u16)?;
        let mut d = ImageDecoderBuf::new();
        let f = decode(&mut d, &twelve)?;
        assert_eq!(f.gray_at(15, 15), 255);
        assert_eq!(f.gray_at(8, 0), 128);
        assert!(!f.has_color);
        // The depth is kept for the sequence: a brighter sample saturates, nothing rescales.
        let brighter = encode_png_gray16(16, 16, |x, _| if x == 0 { 8000 } else { 2048 })?;
        let f = decode(&mut d, &brighter)?;
        assert_eq!((f.gray_at(0, 3), f.gray_at(5, 3)), (255, 128));
        // Full 16-bit content keeps the high byte; 8 bits in 16 are taken as they are.
        let full = encode_png_gray16(16, 16, |x, _| (x * 4096) as u16)?;
        let f = decode(&mut ImageDecoderBuf::new(), &full)?;
        assert_eq!(f.gray_at(8, 0), 128);
        let eight = encode_png_gray16(16, 16, |x, _| (x * 16) as u16)?;
        let f = decode(&mut ImageDecoderBuf::new(), &eight)?;
        assert_eq!(f.gray_at(8, 0), 128);
        // A black first frame does not fix the depth; the first frame with content does.
        let mut d = ImageDecoderBuf::new();
        let black = encode_png_gray16(16, 16, |_, _| 3)?;
        assert_eq!(decode(&mut d, &black)?.gray_at(4, 4), 0);
        assert_eq!(decode(&mut d, &twelve)?.gray_at(8, 0), 128);
        Ok(())
    }
}
