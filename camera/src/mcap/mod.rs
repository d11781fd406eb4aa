//! MCAP replays (ROS 2 bags and Foxglove recordings): one more file-backed source, with the
//! same pacing, skip-and-count and error rules as the image-list replays.
//!
//! The file is read twice, both times streaming (memory scales with the largest chunk, not
//! the file): a scan at open finds the image topics, their frame counts and timestamps and a
//! `CameraInfo`, and notes where a truncated or corrupt file stops being readable; the replay
//! then decodes each image message straight from the reader's buffer into the caller's frame.

pub mod cdr;
pub mod messages;
pub mod write;

use std::fs::File;
use std::io::Read;
use std::path::{Path, PathBuf};

use mcap::records::{op, Record};
use mcap::sans_io::{LinearReadEvent, LinearReader, LinearReaderOptions};

use crate::decode::ImageDecoderBuf;
use crate::{Frame, FrameSource, FrameStatus, SourceError, SourceInfo};
/// The MCAP library, for writer options (compression, chunking).
pub use mcap as format;
use messages::{decode_image, ImagePayload};
pub use messages::{CameraInfo, ImageSchema};

/// Which clock gives a frame its timestamp.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum StampSource {
    /// The message header's stamp (the camera driver's capture time); the MCAP log time when
    /// the stamp is zero.
    #[default]
    Header,
    /// The MCAP record's log time (when the recorder received the message).
    LogTime,
}

impl StampSource {
    pub fn describe(self) -> &'static str {
        match self {
            StampSource::Header => "header stamps",
            StampSource::LogTime => "MCAP log times",
        }
    }
}

/// Largest record accepted: a corrupt length cannot make the reader allocate gigabytes.
const RECORD_LIMIT: usize = 512 << 20;

/// Pulls records from a file through the sans-io reader, counting the bytes fed to it so an
/// error can say where in the file it happened.
struct RecordPump {
    file: File,
    reader: LinearReader,
    fed: u64,
}

impl RecordPump {
    fn open(path: &Path) -> Result<Self, SourceError> {
        let file = File::open(path).map_err(|e| SourceError::io(path, e))?;
        let options = LinearReaderOptions::default().with_record_length_limit(RECORD_LIMIT);
        Ok(RecordPump {
            file,
            reader: LinearReader::new_with_options(options),
            fed: 0,
        })
    }

    /// Calls `f` with the next record; `None` at the end of the file.
    fn next<R>(&mut self, f: impl FnOnce(Record<'_>) -> R) -> Option<Result<R, String>> {
        loop {
            let need = match self.reader.next_event()? {
                Err(e) => return Some(Err(e.to_string())),
                Ok(LinearReadEvent::ReadRequest(n)) => n,
                Ok(LinearReadEvent::Record { data, opcode }) => {
                    if !matches!(opcode, op::SCHEMA | op::CHANNEL | op::MESSAGE) {
                        continue;
                    }
                    return Some(
                        mcap::parse_record(opcode, data)
                            .map(f)
                            .map_err(|e| e.to_string()),
                    );
                }
            };
            let n = loop {
                match self.file.read(self.reader.insert(need)) {
                    Ok(n) => break n,
                    Err(e) if e.kind() == std::io::ErrorKind::Interrupted => continue,
                    Err(e) => return Some(Err(e.to_string())),
                }
            };
            self.reader.notify_read(n);
            self.fed += n as u64;
        }
    }
}

/// One channel as the scan saw it.
#[derive(Clone, Debug)]
pub struct TopicInfo {
    pub topic: String,
    pub schema: String,
    pub message_encoding: String,
    pub messages: usize,
}

/// An image channel's schema, or why it cannot be decoded.
type ImageChannel = Result<ImageSchema, String>;

/// What the scan of the whole file found.
struct Scan {
    topics: Vec<TopicInfo>,
    /// Channel id -> index in `topics` and the image schema, when it carries images.
    channels: Vec<(u16, usize, Option<ImageChannel>)>,
    /// Stamps of each image topic's messages, in file order.
    stamps: Vec<(usize, Vec<f64>)>,
    camera_infos: Vec<(usize, CameraInfo)>,
    /// A read error and the byte count reached, when the file is truncated or corrupt.
    error: Option<(String, u64)>,
}

fn scan(path: &Path, stamp_source: StampSource) -> Result<Scan, SourceError> {
    let mut pump = RecordPump::open(path)?;
    let mut schemas: Vec<(u16, String, String)> = Vec::new();
    let mut s = Scan {
        topics: Vec::new(),
        channels: Vec::new(),
        stamps: Vec::new(),
        camera_infos: Vec::new(),
        error: None,
    };
    while let Some(r) = pump.next(|rec| match rec {
        Record::Schema { header, .. } => {
            schemas.retain(|x| x.0 != header.id);
            schemas.push((header.id, header.name, header.encoding));
        }
        Record::Channel(c) => {
            let schema = schemas.iter().find(|x| x.0 == c.schema_id);
            let name = schema.map(|x| x.1.clone()).unwrap_or_default();
            let topic = match s.topics.iter().position(|t| t.topic == c.topic) {
                Some(i) => i,
                None => {
                    s.topics.push(TopicInfo {
                        topic: c.topic.clone(),
                        schema: name.clone(),
                        message_encoding: c.message_encoding.clone(),
                        messages: 0,
                    });
                    s.topics.len() - 1
                }
            };
            let image = ImageSchema::of(&name, &c.message_encoding);
            s.channels.retain(|x| x.0 != c.id);
            s.channels.push((c.id, topic, image));
        }
        Record::Message { header, data } => {
            let Some((_, topic, image)) = s.channels.iter().find(|x| x.0 == header.channel_id)
            else {
                return;
            };
            let topic = *topic;
            s.topics[topic].messages += 1;
            let tinfo = &s.topics[topic];
            match image {
                Some(Ok(schema)) => {
                    let stamp = match (stamp_source, decode_image(*schema, &data)) {
                        (StampSource::Header, Ok(m)) => m.stamp,
                        _ => None,
                    }
                    .unwrap_or(header.log_time as f64 * 1e-9);
                    match s.stamps.iter_mut().find(|x| x.0 == topic) {
                        Some(v) => v.1.push(stamp),
                        None => s.stamps.push((topic, vec![stamp])),
                    }
                }
                _ if ImageSchema::is_camera_info(&tinfo.schema)
                    && tinfo.message_encoding == "cdr"
                    && !s.camera_infos.iter().any(|x| x.0 == topic) =>
                {
                    if let Ok(info) = messages::decode_camera_info(&data) {
                        s.camera_infos.push((topic, info));
                    }
                }
                _ => {}
            }
        }
        _ => {}
    }) {
        if let Err(e) = r {
            s.error = Some((e, pump.fed));
            break;
        }
    }
    Ok(s)
}

/// Replays the images of one topic of an MCAP file.
pub struct McapSource {
    info: SourceInfo,
    path: PathBuf,
    topic: String,
    /// Channel ids carrying the topic, with their schema.
    channels: Vec<(u16, ImageSchema)>,
    stamps: Vec<f64>,
    camera_info: Option<CameraInfo>,
    stamp_source: StampSource,
    /// Where the scan stopped reading, for a truncated or corrupt file.
    scan_error: Option<(String, u64)>,
    pump: RecordPump,
    decoder: ImageDecoderBuf,
    /// Image messages of the topic read so far (the next frame's index).
    next: usize,
    /// Frames to replay (`limit`), at most `stamps.len()`.
    end: usize,
    last_stamp: f64,
    /// The scan's error was returned.
    reported: bool,
}

impl McapSource {
    /// Opens `path` and picks the image topic: `topic` when given, else the only image topic
    /// in the file. A missing topic (or several candidates) is an error that lists the
    /// topics.
    pub fn open(
        path: &Path,
        topic: Option<&str>,
        stamp_source: StampSource,
    ) -> Result<Self, SourceError> {
        let invalid = |message: String| SourceError::Invalid {
            path: path.to_path_buf(),
            message,
        };
        let s = scan(path, stamp_source)?;
        if s.topics.is_empty() {
            return Err(invalid(match &s.error {
                Some((e, at)) => format!("not a readable MCAP file (at byte {at}: {e})"),
                None => "the MCAP file holds no channels".into(),
            }));
        }
        let listing = || {
            s.topics
                .iter()
                .map(|t| format!("{} ({}, {} messages)", t.topic, t.schema, t.messages))
                .collect::<Vec<_>>()
                .join(", ")
        };
        let is_image = |i: usize| {
            s.channels
                .iter()
                .any(|c| c.1 == i && matches!(c.2, Some(Ok(_))))
        };
        let chosen = match topic {
            Some(t) => {
                let Some(i) = s.topics.iter().position(|x| x.topic == t) else {
                    return Err(invalid(format!(
                        "no topic `{t}`; the file has: {}",
                        listing()
                    )));
                };
                if let Some((_, _, Some(Err(e)))) = s.channels.iter().find(|c| c.1 == i) {
                    return Err(invalid(format!("topic `{t}`: {e}")));
                }
                if !is_image(i) {
                    return Err(invalid(format!(
                        "topic `{t}` carries {}, not images (sensor_msgs/msg/Image or CompressedImage, foxglove.RawImage or CompressedImage); the file has: {}",
                        s.topics[i].schema,
                        listing()
                    )));
                }
                i
            }
            None => {
                let images: Vec<usize> = (0..s.topics.len()).filter(|&i| is_image(i)).collect();
                match images[..] {
                    [i] => i,
                    [] => {
                        return Err(invalid(format!(
                            "no image topic this reader decodes; the file has: {}",
                            listing()
                        )))
                    }
                    _ => {
                        return Err(invalid(format!(
                            "several image topics, choose one with --topic: {}",
                            images
                                .iter()
                                .map(|&i| s.topics[i].topic.as_str())
                                .collect::<Vec<_>>()
                                .join(", ")
                        )))
                    }
                }
            }
        };
        let stamps = s
            .stamps
            .iter()
            .find(|x| x.0 == chosen)
            .map(|x| x.1.clone())
            .unwrap_or_default();
        let topic = s.topics[chosen].topic.clone();
        if stamps.is_empty() {
            return Err(invalid(format!("topic `{topic}` has no messages")));
        }
        // The calibration of `/ns/image_raw` (or `/ns/image_raw/compressed`) is
        // `/ns/camera_info`: the nearest camera_info whose namespace holds the image topic.
        let camera_info = s
            .camera_infos
            .iter()
            .filter_map(|(i, info)| {
                let ns = s.topics[*i].topic.rsplit_once('/').map_or("", |x| x.0);
                topic
                    .starts_with(&format!("{ns}/"))
                    .then_some((ns.len(), info))
            })
            .max_by_key(|x| x.0)
            .map(|x| x.1.clone());
        let channels = s
            .channels
            .iter()
            .filter(|c| c.1 == chosen)
            .filter_map(|c| match &c.2 {
                Some(Ok(schema)) => Some((c.0, *schema)),
                _ => None,
            })
            .collect();
        let mut src = McapSource {
            info: SourceInfo {
                name: format!("{} {topic} ({})", path.display(), stamp_source.describe()),
                width: 0,
                height: 0,
                fps: crate::files::median_rate(&stamps),
                has_color: false,
                len: Some(stamps.len()),
            },
            path: path.to_path_buf(),
            topic,
            channels,
            end: stamps.len(),
            stamps,
            camera_info,
            stamp_source,
            scan_error: s.error,
            pump: RecordPump::open(path)?,
            decoder: ImageDecoderBuf::new(),
            next: 0,
            last_stamp: f64::NEG_INFINITY,
            reported: false,
        };
        src.probe()?;
        Ok(src)
    }

    /// Size and colour from the first decodable image (of the first five), then rewinds.
    fn probe(&mut self) -> Result<(), SourceError> {
        let mut frame = Frame::new(0, 0);
        let mut first_err = None;
        for _ in 0..5 {
            match self.next_frame(&mut frame)? {
                FrameStatus::Ready => {
                    self.info.width = frame.width;
                    self.info.height = frame.height;
                    self.info.has_color = frame.has_color;
                    self.rewind()?;
                    return Ok(());
                }
                FrameStatus::Skipped { reason, .. } => {
                    first_err.get_or_insert(reason);
                }
                FrameStatus::End => break,
            }
        }
        Err(SourceError::Invalid {
            path: self.path.clone(),
            message: format!(
                "topic `{}`: no decodable image among the first frames ({})",
                self.topic,
                first_err.unwrap_or_else(|| "no frames".into())
            ),
        })
    }

    fn rewind(&mut self) -> Result<(), SourceError> {
        self.pump = RecordPump::open(&self.path)?;
        self.next = 0;
        self.last_stamp = f64::NEG_INFINITY;
        self.reported = false;
        Ok(())
    }

    /// The image topic being replayed.
    pub fn topic(&self) -> &str {
        &self.topic
    }

    /// The `CameraInfo` published beside the image topic (same namespace), if any.
    pub fn camera_info(&self) -> Option<&CameraInfo> {
        self.camera_info.as_ref()
    }

    pub fn stamp_source(&self) -> StampSource {
        self.stamp_source
    }

    /// Timestamps of every frame of the topic (up to a truncation), in file order.
    pub fn timestamps(&self) -> &[f64] {
        &self.stamps[..self.end]
    }

    /// Replays only the first `count` frames.
    pub fn limit(&mut self, count: Option<usize>) {
        if let Some(c) = count {
            self.end = self.end.min(c);
        }
        self.info.len = Some(self.end);
    }
}

impl FrameSource for McapSource {
    fn info(&self) -> &SourceInfo {
        &self.info
    }

    fn next_frame(&mut self, out: &mut Frame) -> Result<FrameStatus, SourceError> {
        if self.next >= self.end {
            // A damaged file: the frames before the damage were replayed, now say why it ends
            // here (once; a replay cut by `limit` ends quietly).
            if self.end == self.stamps.len() && self.scan_error.is_some() && !self.reported {
                self.reported = true;
                return Err(self.read_error(""));
            }
            return Ok(FrameStatus::End);
        }
        let expect = (self.info.width > 0).then_some((self.info.width, self.info.height));
        let (channels, decoder, stamp_source) =
            (&self.channels, &mut self.decoder, self.stamp_source);
        let path = &self.path;
        loop {
            let got = self.pump.next(|rec| {
                let Record::Message { header, data } = rec else {
                    return None;
                };
                let schema = channels.iter().find(|c| c.0 == header.channel_id)?.1;
                let log_time = header.log_time as f64 * 1e-9;
                Some(
                    decode_into(schema, &data, expect, decoder, path, out).map(|stamp| {
                        match stamp_source {
                            StampSource::Header => stamp.unwrap_or(log_time),
                            StampSource::LogTime => log_time,
                        }
                    }),
                )
            });
            let index = self.next as u64;
            match got {
                None => {
                    // The scan counted more frames than a second read finds: the file changed.
                    return Err(
                        self.read_error("the file ended early (changed since it was opened?)")
                    );
                }
                Some(Err(e)) => return Err(self.read_error(&e)),
                Some(Ok(None)) => continue,
                Some(Ok(Some(Err(reason)))) => {
                    self.next += 1;
                    return Ok(FrameStatus::Skipped { index, reason });
                }
                Some(Ok(Some(Ok(stamp)))) => {
                    self.next += 1;
                    if stamp.is_nan() || stamp <= self.last_stamp {
                        return Ok(FrameStatus::Skipped {
                            index,
                            reason: format!(
                                "timestamp {stamp:.9} does not increase (previous {:.9})",
                                self.last_stamp
                            ),
                        });
                    }
                    self.last_stamp = stamp;
                    out.timestamp = stamp;
                    out.index = index;
                    return Ok(FrameStatus::Ready);
                }
            }
        }
    }
}

impl McapSource {
    fn read_error(&self, e: &str) -> SourceError {
        let (what, at) = match &self.scan_error {
            Some((scan_e, at)) => (scan_e.as_str(), *at),
            None => (e, self.pump.fed),
        };
        SourceError::Invalid {
            path: self.path.clone(),
            message: format!(
                "corrupt or truncated MCAP after message {} of topic `{}` (read {at} bytes): {what}",
                self.next, self.topic
            ),
        }
    }
}

/// Decodes one image message into `out`; its header stamp on success.
fn decode_into(
    schema: ImageSchema,
    data: &[u8],
    expect: Option<(u32, u32)>,
    decoder: &mut ImageDecoderBuf,
    path: &Path,
    out: &mut Frame,
) -> Result<Option<f64>, String> {
    let msg = decode_image(schema, data)?;
    match msg.payload {
        ImagePayload::Raw {
            width,
            height,
            encoding,
            big_endian,
            step,
            data,
        } => {
            if let Some((w, h)) = expect.filter(|&e| e != (width, height)) {
                return Err(format!("image is {width}x{height}, expected {w}x{h}"));
            }
            let wide = decoder.wide_samples();
            messages::raw_to_frame(width, height, encoding, big_endian, step, data, wide, out)?
        }
        ImagePayload::Compressed { data, .. } => decoder
            .decode(data, path, expect, out)
            .map_err(|e| e.to_string())?,
    }
    Ok(msg.stamp)
}

/// True when `path` looks like an MCAP file (by its magic, whatever its name).
pub fn is_mcap(path: &Path) -> bool {
    crate::capped::read_head(path, 8).is_ok_and(|h| h.starts_with(b"\x89MCAP"))
}

#[cfg(test)]
mod tests;
