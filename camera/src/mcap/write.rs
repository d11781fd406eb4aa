//! Writing image bags: ROS 2 `sensor_msgs/msg/Image` (or `CompressedImage`) and `CameraInfo`
//! in CDR, what `ros2 bag record` with the MCAP storage plugin produces. Used to turn any
//! source (the built-in sequence, a folder) into a bag, and by the tests.

use std::collections::BTreeMap;
use std::io::{Seek, Write};

use mcap::records::MessageHeader;

use super::cdr::CdrWriter;
use super::messages::CameraInfo;
use crate::Frame;

const HEADER_DEFS: &str =
    "================================================================================
MSG: std_msgs/Header
builtin_interfaces/Time stamp
string frame_id
================================================================================
MSG: builtin_interfaces/Time
int32 sec
uint32 nanosec
";

/// How images are stored in the bag.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BagImages {
    /// `sensor_msgs/msg/Image`, `rgb8` for colour frames, `mono8` for grey ones.
    Raw,
    /// `sensor_msgs/msg/CompressedImage` in PNG (lossless).
    Png,
    /// `sensor_msgs/msg/CompressedImage` in JPEG (quality 95).
    Jpeg,
}

/// Writes frames of one camera to an MCAP bag. `finish` must be called to write the summary.
pub struct RosBagWriter<W: Write + Seek> {
    mcap: mcap::Writer<W>,
    image_channel: u16,
    info_channel: u16,
    images: BagImages,
    frame_id: String,
    cdr: CdrWriter,
    encoded: Vec<u8>,
    sequence: u32,
}

/// Nanoseconds of a timestamp in seconds (negative times clamp to 0).
pub fn to_ns(t: f64) -> u64 {
    (t.max(0.0) * 1e9).round() as u64
}

impl<W: Write + Seek> RosBagWriter<W> {
    /// Starts a bag with topics `{ns}/image_raw` (or `{ns}/image_raw/compressed`) and
    /// `{ns}/camera_info`, e.g. `ns` = `/camera`.
    pub fn new(w: W, ns: &str, images: BagImages) -> mcap::McapResult<Self> {
        Self::with_options(w, ns, images, mcap::WriteOptions::new())
    }

    /// [`RosBagWriter::new`] with the MCAP writer's options (compression, chunking).
    pub fn with_options(
        w: W,
        ns: &str,
        images: BagImages,
        opts: mcap::WriteOptions,
    ) -> mcap::McapResult<Self> {
        let opts = opts
            .profile("ros2")
            .library(concat!("sdslam-camera ", env!("CARGO_PKG_VERSION")));
        let mut mcap = opts.create(w)?;
        let (schema, text, topic) = match images {
            BagImages::Raw => (
                "sensor_msgs/msg/Image",
                "std_msgs/Header header\nuint32 height\nuint32 width\nstring encoding\nuint8 is_bigendian\nuint32 step\nuint8[] data\n",
                format!("{ns}/image_raw"),
            ),
            BagImages::Png | BagImages::Jpeg => (
                "sensor_msgs/msg/CompressedImage",
                "std_msgs/Header header\nstring format\nuint8[] data\n",
                format!("{ns}/image_raw/compressed"),
            ),
        };
        let none = BTreeMap::new();
        let image_schema =
            mcap.add_schema(schema, "ros2msg", format!("{text}{HEADER_DEFS}").as_bytes())?;
        let image_channel = mcap.add_channel(image_schema, &topic, "cdr", &none)?;
        let info_text = "std_msgs/Header header\nuint32 height\nuint32 width\nstring distortion_model\nfloat64[] d\nfloat64[9] k\nfloat64[9] r\nfloat64[12] p\nuint32 binning_x\nuint32 binning_y\nsensor_msgs/RegionOfInterest roi\n";
        let roi = "================================================================================\nMSG: sensor_msgs/RegionOfInterest\nuint32 x_offset\nuint32 y_offset\nuint32 height\nuint32 width\nbool do_rectify\n";
        let info_schema = mcap.add_schema(
            "sensor_msgs/msg/CameraInfo",
            "ros2msg",
            format!("{info_text}{HEADER_DEFS}{roi}").as_bytes(),
        )?;
        let info_channel =
            mcap.add_channel(info_schema, &format!("{ns}/camera_info"), "cdr", &none)?;
        Ok(RosBagWriter {
            mcap,
            image_channel,
            info_channel,
            images,
            frame_id: "camera".into(),
            cdr: CdrWriter::new(),
            encoded: Vec::new(),
            sequence: 0,
        })
    }

    fn header(&self, channel_id: u16, stamp_ns: u64) -> MessageHeader {
        MessageHeader {
            channel_id,
            sequence: self.sequence,
            log_time: stamp_ns,
            publish_time: stamp_ns,
        }
    }

    /// Writes the calibration at time `t` (seconds).
    pub fn write_camera_info(&mut self, t: f64, info: &CameraInfo) -> mcap::McapResult<()> {
        let ns = to_ns(t);
        let c = &mut self.cdr;
        c.reset();
        c.header(ns, &self.frame_id);
        c.u32(info.height);
        c.u32(info.width);
        c.string(&info.distortion_model);
        c.u32(info.d.len() as u32);
        for &v in &info.d {
            c.f64(v);
        }
        let identity = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0];
        for &v in info.k.iter().chain(&identity).chain(&info.p) {
            c.f64(v);
        }
        for _ in 0..6 {
            c.u32(0); // binning x, y; roi x, y, height, width
        }
        c.u8(0); // roi.do_rectify
        let header = self.header(self.info_channel, ns);
        self.mcap
            .write_to_known_channel(&header, self.cdr.as_bytes())
    }

    /// Writes one frame, stamped with its timestamp (header stamp and log time).
    pub fn write_frame(&mut self, frame: &Frame) -> mcap::McapResult<()> {
        let ns = to_ns(frame.timestamp);
        let (w, h) = (frame.width, frame.height);
        let pixels: &[u8] = if frame.has_color {
            &frame.rgb
        } else {
            &frame.gray
        };
        let c = &mut self.cdr;
        c.reset();
        c.header(ns, &self.frame_id);
        match self.images {
            BagImages::Raw => {
                let (enc, bpp) = if frame.has_color {
                    ("rgb8", 3)
                } else {
                    ("mono8", 1)
                };
                c.u32(h);
                c.u32(w);
                c.string(enc);
                c.u8(0);
                c.u32(w * bpp);
                c.bytes(pixels);
            }
            BagImages::Png | BagImages::Jpeg => {
                let color = if frame.has_color {
                    image::ExtendedColorType::Rgb8
                } else {
                    image::ExtendedColorType::L8
                };
                self.encoded.clear();
                let r = match self.images {
                    BagImages::Png => image::codecs::png::PngEncoder::new(&mut self.encoded)
                        .write_image(pixels, w, h, color),
                    _ => image::codecs::jpeg::JpegEncoder::new_with_quality(&mut self.encoded, 95)
                        .encode(pixels, w, h, color),
                };
                r.map_err(|e| mcap::McapError::Io(std::io::Error::other(e.to_string())))?;
                c.string(if self.images == BagImages::Png {
                    "png"
                } else {
                    "jpeg"
                });
                c.bytes(&self.encoded);
            }
        }
        let header = self.header(self.image_channel, ns);
        self.mcap
            .write_to_known_channel(&header, self.cdr.as_bytes())?;
        self.sequence += 1;
        Ok(())
    }

    /// Writes the summary and returns the underlying writer.
    pub fn finish(mut self) -> mcap::McapResult<W> {
        self.mcap.finish()?;
        Ok(self.mcap.into_inner())
    }
}

use image::ImageEncoder as _;
