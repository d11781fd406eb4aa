//! Device modes and the choice among them: the size the calibration fixes, a frame rate that
//! keeps up, then the cheapest pixel format to turn into grey (GREY, then YUYV, then MJPEG).

use super::DeviceError;

/// Pixel formats sdslam converts. Others are listed but never chosen.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum PixelFormat {
    /// 8-bit grey (`GREY`, also called Y8): copied as is.
    Grey,
    /// Packed 4:2:2 `YUYV`: the Y bytes are the grey image.
    Yuyv,
    /// Motion JPEG: decoded per frame into a reused buffer.
    Mjpeg,
    /// Anything else, by its FourCC.
    Other([u8; 4]),
}

impl PixelFormat {
    pub fn from_fourcc(code: [u8; 4]) -> Self {
        match &code {
            b"GREY" | b"Y800" | b"Y8  " => PixelFormat::Grey,
            b"YUYV" | b"YUY2" => PixelFormat::Yuyv,
            b"MJPG" | b"JPEG" => PixelFormat::Mjpeg,
            _ => PixelFormat::Other(code),
        }
    }

    pub fn fourcc(self) -> [u8; 4] {
        match self {
            PixelFormat::Grey => *b"GREY",
            PixelFormat::Yuyv => *b"YUYV",
            PixelFormat::Mjpeg => *b"MJPG",
            PixelFormat::Other(c) => c,
        }
    }

    /// Rank among usable formats (lower is better), `None` when sdslam cannot convert it.
    pub fn preference(self) -> Option<u8> {
        match self {
            PixelFormat::Grey => Some(0),
            PixelFormat::Yuyv => Some(1),
            PixelFormat::Mjpeg => Some(2),
            PixelFormat::Other(_) => None,
        }
    }

    /// True when frames of this format carry colour (for colouring the semi-dense cloud).
    pub fn has_color(self) -> bool {
        matches!(self, PixelFormat::Yuyv | PixelFormat::Mjpeg)
    }
}

impl std::fmt::Display for PixelFormat {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let c = self.fourcc();
        write!(f, "{}", String::from_utf8_lossy(&c).trim_end())
    }
}

/// One size of one format with the frame rates the device offers for it.
#[derive(Clone, Debug, PartialEq)]
pub struct Mode {
    pub format: PixelFormat,
    pub width: u32,
    pub height: u32,
    /// Frame rates (frames per second), empty when the device does not say.
    pub fps: Vec<f64>,
}

/// What the caller wants; unset fields are free.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ModeRequest {
    /// Exact image size (the calibration's): a camera mode of another size would make the
    /// intrinsics wrong, so it is never chosen.
    pub size: Option<(u32, u32)>,
    /// Wanted frame rate; modes slower than this rank last.
    pub fps: Option<f64>,
    /// Force a pixel format.
    pub format: Option<PixelFormat>,
}

/// The chosen mode: format, size and the frame rate to ask for.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ChosenMode {
    pub format: PixelFormat,
    pub width: u32,
    pub height: u32,
    pub fps: f64,
}

/// Default size when nothing is requested: 640x480 is what ORB parameters are published for.
pub const DEFAULT_SIZE: (u32, u32) = (640, 480);
/// Default frame rate when nothing is requested.
pub const DEFAULT_FPS: f64 = 30.0;

/// Picks the mode to stream. Order: usable format and right size (required), a frame rate at
/// least the wanted one, the format preference (GREY < YUYV < MJPEG: a webcam's YUYV at 30 fps
/// beats its MJPEG, but MJPEG at 30 beats YUYV at 10), then the frame rate nearest the wanted.
pub fn choose_mode(
    device: &str,
    modes: &[Mode],
    req: &ModeRequest,
) -> Result<ChosenMode, DeviceError> {
    let want_fps = req.fps.unwrap_or(DEFAULT_FPS);
    let size = match req.size {
        Some(s) => s,
        None => nearest_size(modes, req.format).unwrap_or(DEFAULT_SIZE),
    };
    let mut best: Option<((bool, u8, u64), ChosenMode)> = None;
    for m in modes {
        let Some(pref) = m.format.preference() else {
            continue;
        };
        if (m.width, m.height) != size || req.format.is_some_and(|f| f != m.format) {
            continue;
        }
        // A device that lists no rates streams at whatever it does: assume the wanted one.
        let rates: &[f64] = if m.fps.is_empty() {
            &[want_fps]
        } else {
            &m.fps
        };
        for &fps in rates {
            let slow = fps + 1e-3 < want_fps;
            // Among fast-enough rates the lowest (least bandwidth), among slow ones the highest.
            let dist = ((fps - want_fps).abs() * 1000.0) as u64;
            let key = (slow, pref, dist);
            if best.as_ref().is_none_or(|(k, _)| key < *k) {
                best = Some((
                    key,
                    ChosenMode {
                        format: m.format,
                        width: m.width,
                        height: m.height,
                        fps,
                    },
                ));
            }
        }
    }
    best.map(|(_, c)| c)
        .ok_or_else(|| DeviceError::NoUsableMode {
            device: device.to_string(),
            message: format!(
                "wanted {}x{}{}; the device offers {}",
                size.0,
                size.1,
                req.format.map(|f| format!(" {f}")).unwrap_or_default(),
                describe_modes(modes)
            ),
        })
}

/// With no size requested: 640x480 when offered in a usable format, else the usable size
/// nearest to it in pixel count.
fn nearest_size(modes: &[Mode], format: Option<PixelFormat>) -> Option<(u32, u32)> {
    let target = (DEFAULT_SIZE.0 * DEFAULT_SIZE.1) as i64;
    modes
        .iter()
        .filter(|m| m.format.preference().is_some() && format.is_none_or(|f| f == m.format))
        .min_by_key(|m| ((m.width as i64 * m.height as i64) - target).abs())
        .map(|m| (m.width, m.height))
}

/// One line per format: `YUYV 640x480@30,15 1280x720@10`.
pub fn describe_modes(modes: &[Mode]) -> String {
    if modes.is_empty() {
        return "no modes".into();
    }
    let mut out = String::new();
    let mut last: Option<PixelFormat> = None;
    for m in modes {
        if last != Some(m.format) {
            if last.is_some() {
                out.push_str("; ");
            }
            out.push_str(&m.format.to_string());
            last = Some(m.format);
        }
        out.push_str(&format!(" {}x{}", m.width, m.height));
        if !m.fps.is_empty() {
            let rates: Vec<String> = m
                .fps
                .iter()
                .map(|f| format!("{}", (f * 100.0).round() / 100.0))
                .collect();
            out.push_str(&format!("@{}", rates.join(",")));
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn webcam() -> Vec<Mode> {
        vec![
            Mode {
                format: PixelFormat::Yuyv,
                width: 640,
                height: 480,
                fps: vec![30.0, 15.0],
            },
            Mode {
                format: PixelFormat::Yuyv,
                width: 1280,
                height: 720,
                fps: vec![10.0],
            },
            Mode {
                format: PixelFormat::Mjpeg,
                width: 640,
                height: 480,
                fps: vec![30.0],
            },
            Mode {
                format: PixelFormat::Mjpeg,
                width: 1280,
                height: 720,
                fps: vec![30.0],
            },
            Mode {
                format: PixelFormat::Other(*b"H264"),
                width: 1920,
                height: 1080,
                fps: vec![30.0],
            },
        ]
    }

    #[test]
    fn prefers_grey_then_yuyv_then_mjpeg_at_the_same_rate() {
        let c = choose_mode("cam", &webcam(), &ModeRequest::default()).unwrap();
        assert_eq!(
            (c.format, c.width, c.height, c.fps),
            (PixelFormat::Yuyv, 640, 480, 30.0)
        );
        let mut modes = webcam();
        modes.push(Mode {
            format: PixelFormat::Grey,
            width: 640,
            height: 480,
            fps: vec![60.0, 30.0],
        });
        let c = choose_mode("cam", &modes, &ModeRequest::default()).unwrap();
        assert_eq!((c.format, c.fps), (PixelFormat::Grey, 30.0));
    }

    #[test]
    fn a_fast_enough_mjpeg_beats_a_slow_yuyv() {
        let req = ModeRequest {
            size: Some((1280, 720)),
            fps: Some(30.0),
            format: None,
        };
        let c = choose_mode("cam", &webcam(), &req).unwrap();
        assert_eq!(c.format, PixelFormat::Mjpeg);
        // Asking for 10 fps, YUYV is fast enough and preferred.
        let req = ModeRequest {
            fps: Some(10.0),
            ..req
        };
        assert_eq!(
            choose_mode("cam", &webcam(), &req).unwrap().format,
            PixelFormat::Yuyv
        );
    }

    #[test]
    fn never_picks_another_size_than_the_calibration() {
        let req = ModeRequest {
            size: Some((752, 480)),
            ..Default::default()
        };
        let e = choose_mode("/dev/video0", &webcam(), &req).unwrap_err();
        let msg = e.to_string();
        assert!(
            msg.contains("/dev/video0") && msg.contains("752x480"),
            "{msg}"
        );
        assert!(msg.contains("YUYV 640x480@30,15"), "{msg}");
    }

    #[test]
    fn unusable_formats_only_is_a_clear_error() {
        let modes = vec![Mode {
            format: PixelFormat::Other(*b"H264"),
            width: 640,
            height: 480,
            fps: vec![],
        }];
        assert!(matches!(
            choose_mode("cam", &modes, &ModeRequest::default()),
            Err(DeviceError::NoUsableMode { .. })
        ));
    }

    #[test]
    fn without_a_size_takes_the_one_nearest_vga() {
        let modes = vec![
            Mode {
                format: PixelFormat::Yuyv,
                width: 320,
                height: 240,
                fps: vec![30.0],
            },
            Mode {
                format: PixelFormat::Yuyv,
                width: 800,
                height: 600,
                fps: vec![30.0],
            },
            Mode {
                format: PixelFormat::Yuyv,
                width: 1920,
                height: 1080,
                fps: vec![5.0],
            },
        ];
        let c = choose_mode("cam", &modes, &ModeRequest::default()).unwrap();
        assert_eq!((c.width, c.height), (800, 600));
    }

    #[test]
    fn devices_that_list_no_rates_get_the_wanted_rate() {
        let modes = vec![Mode {
            format: PixelFormat::Grey,
            width: 640,
            height: 480,
            fps: vec![],
        }];
        let c = choose_mode(
            "cam",
            &modes,
            &ModeRequest {
                fps: Some(20.0),
                ..Default::default()
            },
        )
        .unwrap();
        assert_eq!(c.fps, 20.0);
    }

    #[test]
    fn fourcc_round_trip() {
        for f in [PixelFormat::Grey, PixelFormat::Yuyv, PixelFormat::Mjpeg] {
            assert_eq!(PixelFormat::from_fourcc(f.fourcc()), f);
        }
        assert_eq!(PixelFormat::from_fourcc(*b"Y800"), PixelFormat::Grey);
        assert_eq!(PixelFormat::Mjpeg.to_string(), "MJPG");
    }
}
