//! Exposure and gain. SLAM wants a fixed exposure: auto exposure changes brightness between
//! frames, which breaks the constant-intensity assumption of the semi-dense search and moves
//! FAST responses. Set it where the device offers it; say so where it does not.

use super::{CaptureDevice, DeviceError};

/// Controls sdslam sets.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CameraControl {
    /// V4L2_CID_EXPOSURE_AUTO: menu, 1 = manual, 3 = aperture priority (auto).
    AutoExposure,
    /// V4L2_CID_EXPOSURE_ABSOLUTE, in units of 100 us.
    ExposureTime,
    /// V4L2_CID_AUTOGAIN: boolean.
    AutoGain,
    /// V4L2_CID_GAIN: device units.
    Gain,
}

impl CameraControl {
    /// The V4L2 control id.
    pub fn v4l2_id(self) -> u32 {
        match self {
            CameraControl::AutoExposure => 0x009a_0901,
            CameraControl::ExposureTime => 0x009a_0902,
            CameraControl::AutoGain => 0x0098_0912,
            CameraControl::Gain => 0x0098_0913,
        }
    }

    pub fn from_v4l2_id(id: u32) -> Option<Self> {
        [
            Self::AutoExposure,
            Self::ExposureTime,
            Self::AutoGain,
            Self::Gain,
        ]
        .into_iter()
        .find(|c| c.v4l2_id() == id)
    }
}

/// Range of one control on one device.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ControlInfo {
    pub control: CameraControl,
    pub min: i64,
    pub max: i64,
    pub default: i64,
}

/// Exposure wanted for a run.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Exposure {
    /// Leave the camera's automatic exposure on.
    Auto,
    /// Fixed exposure time in microseconds (recommended for SLAM).
    Manual { micros: u32 },
}

/// V4L2 menu values of `AutoExposure`.
const EXPOSURE_MANUAL: i64 = 1;
const EXPOSURE_APERTURE_PRIORITY: i64 = 3;

/// Applies exposure and gain where the device has the controls. Returns warnings for what could
/// not be done as asked (missing control, value clamped); errors only when a set call fails.
pub fn apply<D: CaptureDevice + ?Sized>(
    dev: &mut D,
    exposure: Option<Exposure>,
    gain: Option<i64>,
) -> Result<Vec<String>, DeviceError> {
    let mut warnings = Vec::new();
    if exposure.is_none() && gain.is_none() {
        return Ok(warnings);
    }
    let controls = dev.controls()?;
    let find = |c| controls.iter().find(|i| i.control == c).copied();
    let name = dev.name().to_string();
    let set =
        |dev: &mut D, info: ControlInfo, value: i64, what: &str, warnings: &mut Vec<String>| {
            let v = value.clamp(info.min, info.max);
            if v != value {
                warnings.push(format!(
                    "{name}: {what} {value} is outside [{}, {}], using {v}",
                    info.min, info.max
                ));
            }
            dev.set_control(info.control, v)
        };
    match exposure {
        Some(Exposure::Manual { micros }) => match (find(CameraControl::AutoExposure), find(CameraControl::ExposureTime)) {
            (auto, Some(time)) => {
                if let Some(auto) = auto {
                    set(dev, auto, EXPOSURE_MANUAL, "auto-exposure mode", &mut warnings)?;
                }
                let units = (micros as i64 + 50) / 100;
                set(dev, time, units, "exposure (100 us units)", &mut warnings)?;
            }
            (_, None) => warnings.push(format!(
                "{name}: the device has no exposure-time control; exposure stays as the camera sets it"
            )),
        },
        Some(Exposure::Auto) => {
            if let Some(auto) = find(CameraControl::AutoExposure) {
                set(dev, auto, EXPOSURE_APERTURE_PRIORITY, "auto-exposure mode", &mut warnings)?;
            }
        }
        None => {}
    }
    if let Some(g) = gain {
        if let Some(auto) = find(CameraControl::AutoGain) {
            set(dev, auto, 0, "auto gain", &mut warnings)?;
        }
        match find(CameraControl::Gain) {
            Some(info) => set(dev, info, g, "gain", &mut warnings)?,
            None => warnings.push(format!("{name}: the device has no gain control")),
        }
    }
    Ok(warnings)
}
