//! Calibration files: ORB-SLAM-style YAML (`Camera.fx` ...) and EuRoC `sensor.yaml`.
//!
//! Parsing is pure (text in, typed calibration or a [`CalibError`] naming file, line and
//! field out); reading the file is the caller's (`io`) job.

use super::yaml::{self, YamlEntry, YamlValue};
use super::{KannalaBrandt, Lens, PinholeRadtan};

/// Horizontal field of view of the pinhole view a fisheye's frames are resampled into
/// (`Camera.viewFov` in the calibration file overrides it). A pinhole view stretches its edges
/// against its centre (1.7x at 90 degrees, 3x at 110), and finer angular resolution won: on the
/// built-in fisheye sequences 90 degrees tracked desk at 1.5 mm keyframe ATE against 2.3 mm
/// (110) and 4.3 mm (130), and the rotation scene with 28 badly-off `Ok` frames against 129
/// (110); the outward loop did better wider (0.048% of the path at 110, 0.076% at 90).
pub const FISHEYE_VIEW_FOV_DEG: f64 = 90.0;

/// A camera calibration as `sdslam run` needs it.
#[derive(Clone, Debug, PartialEq)]
pub struct Calibration {
    /// The undistorted pinhole view every stage works in: the camera itself without its
    /// distortion, or for a fisheye the pinhole view its frames are resampled into.
    pub camera: PinholeRadtan,
    /// The fisheye lens of the raw frames, when they come from one.
    pub fisheye: Option<KannalaBrandt>,
    /// Nominal frame rate; deadlines default to 1/fps.
    pub fps: f64,
}

/// A calibration problem, naming the file, line (when known) and field.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{file}{}: {}{message}", .line.map(|l| format!(":{l}")).unwrap_or_default(), .field.as_ref().map(|f| format!("field `{f}`: ")).unwrap_or_default())]
pub struct CalibError {
    pub file: String,
    pub line: Option<usize>,
    pub field: Option<String>,
    pub message: String,
}

/// ORB-SLAM keys that are accepted but do not affect the camera model.
const ORBSLAM_IGNORED: &[&str] = &[
    "Camera.type",
    "Camera.RGB",
    "Camera.bf",
    "ThDepth",
    "DepthMapFactor",
    "File.version",
    "ORBextractor.nFeatures",
    "ORBextractor.scaleFactor",
    "ORBextractor.nLevels",
    "ORBextractor.iniThFAST",
    "ORBextractor.minThFAST",
];

const EUROC_IGNORED: &[&str] = &["sensor_type", "comment", "camera_model", "distortion_model"];

struct Fields<'a> {
    file: &'a str,
    entries: Vec<YamlEntry>,
}

impl<'a> Fields<'a> {
    fn err(&self, line: Option<usize>, field: &str, msg: impl Into<String>) -> CalibError {
        CalibError {
            file: self.file.to_string(),
            line,
            field: Some(field.to_string()),
            message: msg.into(),
        }
    }

    fn get(&self, key: &str) -> Option<&YamlEntry> {
        self.entries.iter().find(|e| e.key == key)
    }

    fn number_of(&self, e: &YamlEntry, s: &str) -> Result<f64, CalibError> {
        let v: f64 = s
            .trim()
            .parse()
            .map_err(|_| self.err(Some(e.line), &e.key, format!("{s:?} is not a number")))?;
        if !v.is_finite() {
            return Err(self.err(Some(e.line), &e.key, format!("{s:?} is not finite")));
        }
        Ok(v)
    }

    fn scalar(&self, key: &str) -> Result<Option<f64>, CalibError> {
        let Some(e) = self.get(key) else {
            return Ok(None);
        };
        match &e.value {
            YamlValue::Scalar(s) => Ok(Some(self.number_of(e, s)?)),
            _ => Err(self.err(Some(e.line), key, "expected a number")),
        }
    }

    fn required(&self, keys: &[&str]) -> Result<f64, CalibError> {
        for k in keys {
            if let Some(v) = self.scalar(k)? {
                return Ok(v);
            }
        }
        Err(self.err(None, keys[0], "missing"))
    }

    fn seq(&self, key: &str, len: std::ops::RangeInclusive<usize>) -> Result<Vec<f64>, CalibError> {
        let e = self
            .get(key)
            .ok_or_else(|| self.err(None, key, "missing"))?;
        let YamlValue::Seq(items) = &e.value else {
            return Err(self.err(Some(e.line), key, "expected a list [a, b, ...]"));
        };
        if !len.contains(&items.len()) {
            return Err(self.err(
                Some(e.line),
                key,
                format!(
                    "expected {}..={} values, found {}",
                    len.start(),
                    len.end(),
                    items.len()
                ),
            ));
        }
        items.iter().map(|s| self.number_of(e, s)).collect()
    }

    fn size(&self, key: &str, v: f64, line: Option<usize>) -> Result<u32, CalibError> {
        if !(v >= 1.0 && v.fract() == 0.0) {
            return Err(self.err(
                line,
                key,
                format!("{v} is not a positive whole number of pixels"),
            ));
        }
        if v > 65535.0 {
            return Err(self.err(
                line,
                key,
                format!("{v} pixels is beyond the largest image side sdslam accepts (65535)"),
            ));
        }
        Ok(v as u32)
    }
}

fn line_of(f: &Fields, keys: &[&str]) -> Option<usize> {
    keys.iter().find_map(|k| f.get(k).map(|e| e.line))
}

fn syntax(file: &str, e: yaml::YamlSyntaxError) -> CalibError {
    CalibError {
        file: file.to_string(),
        line: Some(e.line),
        field: None,
        message: e.message,
    }
}

/// Narrowest and widest field of view of a pinhole calibration (fisheye lenses beyond it need
/// another camera model).
const MIN_FOV_DEG: f64 = 1.0;
const MAX_FOV_DEG: f64 = 170.0;

impl Calibration {
    /// A pinhole (radial-tangential) camera.
    pub fn pinhole(camera: PinholeRadtan, fps: f64) -> Self {
        Calibration {
            camera,
            fisheye: None,
            fps,
        }
    }

    /// A fisheye camera, tracked in its [`pinhole view`](KannalaBrandt::pinhole_view) of
    /// [`FISHEYE_VIEW_FOV_DEG`].
    pub fn fisheye(lens: KannalaBrandt, fps: f64) -> Self {
        Calibration {
            camera: lens.pinhole_view(FISHEYE_VIEW_FOV_DEG),
            fisheye: Some(lens),
            fps,
        }
    }

    /// The lens of the raw frames.
    pub fn lens(&self) -> Lens {
        match self.fisheye {
            Some(k) => Lens::KannalaBrandt(k),
            None => Lens::Pinhole(self.camera),
        }
    }

    /// Parses either layout, recognised by its keys (`intrinsics` means EuRoC).
    pub fn parse(text: &str, file: &str) -> Result<Self, CalibError> {
        let entries = yaml::parse(text).map_err(|e| syntax(file, e))?;
        let f = Fields { file, entries };
        if f.get("intrinsics").is_some() || f.get("sensor_type").is_some() {
            Self::from_euroc(&f)
        } else {
            Self::from_orbslam(&f)
        }
    }

    fn from_orbslam(f: &Fields) -> Result<Self, CalibError> {
        for e in &f.entries {
            let k = e.key.as_str();
            let camera_key = k
                .strip_prefix("Camera.")
                .or_else(|| k.strip_prefix("Camera1."))
                .is_some_and(|r| {
                    matches!(
                        r,
                        "fx" | "fy"
                            | "cx"
                            | "cy"
                            | "k1"
                            | "k2"
                            | "p1"
                            | "p2"
                            | "k3"
                            | "k4"
                            | "viewFov"
                            | "width"
                            | "height"
                            | "fps"
                    )
                });
            if !(camera_key || ORBSLAM_IGNORED.contains(&k) || k.starts_with("Viewer.")) {
                return Err(f.err(Some(e.line), k, "unknown key"));
            }
        }
        let mut fisheye = false;
        if let Some(e) = f.get("Camera.type") {
            if let YamlValue::Scalar(s) = &e.value {
                if s.eq_ignore_ascii_case("kannalabrandt8") {
                    fisheye = true;
                } else if !s.eq_ignore_ascii_case("pinhole") {
                    return Err(f.err(
                        Some(e.line),
                        "Camera.type",
                        format!("{s:?} is not supported (PinHole with radial-tangential distortion, or KannalaBrandt8)"),
                    ));
                }
            }
        }
        // Coefficients of the other model are mistakes, not zeros.
        let foreign: &[&str] = if fisheye { &["p1", "p2"] } else { &["k4"] };
        for n in foreign {
            for k in [format!("Camera.{n}"), format!("Camera1.{n}")] {
                if let Some(e) = f.get(&k) {
                    return Err(f.err(
                        Some(e.line),
                        &k,
                        if fisheye {
                            "not a KannalaBrandt8 coefficient (k1..k4)"
                        } else {
                            "only a KannalaBrandt8 camera has k4 (set Camera.type)"
                        },
                    ));
                }
            }
        }
        let g = |n: &str| -> Result<f64, CalibError> {
            f.required(&[&format!("Camera.{n}"), &format!("Camera1.{n}")])
        };
        let opt = |n: &str| -> Result<f64, CalibError> {
            Ok(f.scalar(&format!("Camera.{n}"))?
                .or(f.scalar(&format!("Camera1.{n}"))?)
                .unwrap_or(0.0))
        };
        let width = f.size(
            "Camera.width",
            g("width")?,
            line_of(f, &["Camera.width", "Camera1.width"]),
        )?;
        let height = f.size(
            "Camera.height",
            g("height")?,
            line_of(f, &["Camera.height", "Camera1.height"]),
        )?;
        let fps = f
            .scalar("Camera.fps")?
            .or(f.scalar("Camera1.fps")?)
            .unwrap_or(30.0);
        let locate = |n: &str| {
            let keys = [format!("Camera.{n}"), format!("Camera1.{n}")];
            let ks: Vec<&str> = keys.iter().map(|s| s.as_str()).collect();
            (format!("Camera.{n}"), line_of(f, &ks))
        };
        if fisheye {
            let lens = KannalaBrandt {
                fx: g("fx")?,
                fy: g("fy")?,
                cx: g("cx")?,
                cy: g("cy")?,
                k1: opt("k1")?,
                k2: opt("k2")?,
                k3: opt("k3")?,
                k4: opt("k4")?,
                width,
                height,
            };
            validate_fisheye(&lens, fps, f, locate)?;
            let mut calib = Calibration::fisheye(lens, fps);
            if let Some(fov) = f.scalar("Camera.viewFov")?.or(f.scalar("Camera1.viewFov")?) {
                if !(10.0..=150.0).contains(&fov) {
                    let (key, line) = locate("viewFov");
                    return Err(f.err(
                        line,
                        &key,
                        format!("{fov} degrees: the pinhole view takes 10..150"),
                    ));
                }
                calib.camera = lens.pinhole_view(fov);
            }
            return Ok(calib);
        }
        let camera = PinholeRadtan {
            fx: g("fx")?,
            fy: g("fy")?,
            cx: g("cx")?,
            cy: g("cy")?,
            k1: opt("k1")?,
            k2: opt("k2")?,
            p1: opt("p1")?,
            p2: opt("p2")?,
            k3: opt("k3")?,
            width,
            height,
        };
        let calib = Calibration::pinhole(camera, fps);
        calib.validate(f, locate)?;
        Ok(calib)
    }

    fn from_euroc(f: &Fields) -> Result<Self, CalibError> {
        for e in &f.entries {
            let k = e.key.as_str();
            let known = matches!(
                k,
                "intrinsics" | "distortion_coefficients" | "resolution" | "rate_hz"
            ) || k == "T_BS"
                || k.starts_with("T_BS/")
                || EUROC_IGNORED.contains(&k);
            if !known {
                return Err(f.err(Some(e.line), k, "unknown key"));
            }
        }
        if let Some(e) = f.get("camera_model") {
            if e.value != YamlValue::Scalar("pinhole".into()) {
                return Err(f.err(Some(e.line), "camera_model", "only `pinhole` is supported"));
            }
        }
        if let Some(e) = f.get("distortion_model") {
            let ok = matches!(&e.value, YamlValue::Scalar(s) if s == "radial-tangential" || s == "radtan");
            if !ok {
                return Err(f.err(
                    Some(e.line),
                    "distortion_model",
                    "only `radial-tangential` is supported",
                ));
            }
        }
        let k = f.seq("intrinsics", 4..=4)?;
        let d = f.seq("distortion_coefficients", 4..=5)?;
        let r = f.seq("resolution", 2..=2)?;
        let rline = f.get("resolution").map(|e| e.line);
        let camera = PinholeRadtan {
            fx: k[0],
            fy: k[1],
            cx: k[2],
            cy: k[3],
            k1: d[0],
            k2: d[1],
            p1: d[2],
            p2: d[3],
            k3: d.get(4).copied().unwrap_or(0.0),
            width: f.size("resolution", r[0], rline)?,
            height: f.size("resolution", r[1], rline)?,
        };
        let fps = f.scalar("rate_hz")?.unwrap_or(20.0);
        let calib = Calibration::pinhole(camera, fps);
        calib.validate(f, |n| {
            let key = match n {
                "fx" | "fy" | "cx" | "cy" => "intrinsics",
                "fps" => "rate_hz",
                _ => "distortion_coefficients",
            };
            (key.to_string(), f.get(key).map(|e| e.line))
        })?;
        Ok(calib)
    }

    /// Physical sanity: positive focal lengths and frame rate, principal point inside the image.
    fn validate(
        &self,
        f: &Fields,
        locate: impl Fn(&str) -> (String, Option<usize>),
    ) -> Result<(), CalibError> {
        let c = &self.camera;
        let fail = |n: &str, m: String| {
            let (k, l) = locate(n);
            Err(f.err(l, &k, m))
        };
        if c.fx <= 0.0 {
            return fail("fx", format!("focal length {} must be positive", c.fx));
        }
        if c.fy <= 0.0 {
            return fail("fy", format!("focal length {} must be positive", c.fy));
        }
        if c.cx < 0.0 || c.cx > c.width as f64 {
            return fail(
                "cx",
                format!(
                    "principal point {} lies outside the image width {}",
                    c.cx, c.width
                ),
            );
        }
        if c.cy < 0.0 || c.cy > c.height as f64 {
            return fail(
                "cy",
                format!(
                    "principal point {} lies outside the image height {}",
                    c.cy, c.height
                ),
            );
        }
        if self.fps <= 0.0 {
            return fail("fps", format!("frame rate {} must be positive", self.fps));
        }
        // What cannot be a pinhole camera: a field of view outside 1..170 degrees, pixels far
        // from square, or a distortion that folds over or scales the image corners beyond 5x.
        let fov = |f: f64, side: u32| 2.0 * (side as f64 / (2.0 * f)).atan().to_degrees();
        for (name, focal, side) in [("fx", c.fx, c.width), ("fy", c.fy, c.height)] {
            let deg = fov(focal, side);
            if !(MIN_FOV_DEG..=MAX_FOV_DEG).contains(&deg) {
                return fail(
                    name,
                    format!(
                        "focal length {focal} gives a {deg:.3} degree field of view over {side} pixels; a camera has {MIN_FOV_DEG}..{MAX_FOV_DEG}"
                    ),
                );
            }
        }
        let aspect = c.fx / c.fy;
        if !(0.5..=2.0).contains(&aspect) {
            return fail(
                "fy",
                format!("fx / fy = {aspect:.3}: pixels this far from square are not a camera (0.5..2 accepted)"),
            );
        }
        // Radial factor over the undistorted radii up to the image corner's.
        let (dx, dy) = (
            c.cx.max(c.width as f64 - c.cx) / c.fx,
            c.cy.max(c.height as f64 - c.cy) / c.fy,
        );
        let r_corner = (dx * dx + dy * dy).sqrt();
        let factor = |r: f64| {
            let r2 = r * r;
            1.0 + r2 * (c.k1 + r2 * (c.k2 + r2 * c.k3))
        };
        let slope = |r: f64| {
            let r2 = r * r;
            1.0 + r2 * (3.0 * c.k1 + r2 * (5.0 * c.k2 + r2 * 7.0 * c.k3))
        };
        const STEPS: usize = 64;
        for i in 1..=STEPS {
            let r = r_corner * i as f64 / STEPS as f64;
            let s = slope(r);
            if s.is_nan() || s <= 0.0 {
                return fail(
                    "k1",
                    format!(
                        "radial distortion (k1 {}, k2 {}, k3 {}) folds over inside the image (at {:.0}% of the corner radius): not a lens",
                        c.k1, c.k2, c.k3, 100.0 * i as f64 / STEPS as f64
                    ),
                );
            }
        }
        let at_corner = factor(r_corner);
        if !(0.2..=5.0).contains(&at_corner) {
            return fail(
                "k1",
                format!(
                    "radial distortion (k1 {}, k2 {}, k3 {}) scales the image corners by {at_corner:.2}: not a lens (0.2..5 accepted)",
                    c.k1, c.k2, c.k3
                ),
            );
        }
        Ok(())
    }

    /// Checks that images of `width` x `height` fit this calibration.
    pub fn check_image_size(&self, width: u32, height: u32, file: &str) -> Result<(), CalibError> {
        if (width, height) != (self.camera.width, self.camera.height) {
            return Err(CalibError {
                file: file.to_string(),
                line: None,
                field: Some("Camera.width/Camera.height".into()),
                message: format!(
                    "calibration is for {}x{} images but the source gives {width}x{height}",
                    self.camera.width, self.camera.height
                ),
            });
        }
        Ok(())
    }

    /// Writes the ORB-SLAM layout (what `sdslam calibrate` produces and `sdslam run` reads;
    /// ORB-SLAM3's `KannalaBrandt8` for a fisheye).
    pub fn to_orbslam_yaml(&self, comment: &str) -> String {
        let c = &self.camera;
        let mut s = String::from("%YAML:1.0\n");
        for l in comment.lines() {
            s.push_str(&format!("# {l}\n"));
        }
        let (kind, params, (width, height)) = match &self.fisheye {
            Some(k) => (
                "KannalaBrandt8",
                [
                    ("fx", k.fx),
                    ("fy", k.fy),
                    ("cx", k.cx),
                    ("cy", k.cy),
                    ("k1", k.k1),
                    ("k2", k.k2),
                    ("k3", k.k3),
                    ("k4", k.k4),
                ]
                .to_vec(),
                (k.width, k.height),
            ),
            None => (
                "PinHole",
                [
                    ("fx", c.fx),
                    ("fy", c.fy),
                    ("cx", c.cx),
                    ("cy", c.cy),
                    ("k1", c.k1),
                    ("k2", c.k2),
                    ("p1", c.p1),
                    ("p2", c.p2),
                    ("k3", c.k3),
                ]
                .to_vec(),
                (c.width, c.height),
            ),
        };
        s.push_str(&format!("Camera.type: \"{kind}\"\n"));
        for (n, v) in params {
            s.push_str(&format!("Camera.{n}: {v:?}\n"));
        }
        s.push_str(&format!(
            "Camera.width: {width}\nCamera.height: {height}\nCamera.fps: {:?}\n",
            self.fps
        ));
        if let Some(k) = self
            .fisheye
            .filter(|k| *c != k.pinhole_view(FISHEYE_VIEW_FOV_DEG))
        {
            let half_px = k.cx.max(k.width as f64 - 1.0 - k.cx) + 0.5;
            let fov = 2.0 * (half_px / c.fx).atan().to_degrees();
            s.push_str(&format!("Camera.viewFov: {fov:?}\n"));
        }
        s
    }
}

/// Physical sanity of a fisheye: positive focal lengths and frame rate, principal point inside
/// the image, near-square pixels, and a radius polynomial that keeps growing out to the
/// image's sides (else pixels there name no ray).
fn validate_fisheye(
    k: &KannalaBrandt,
    fps: f64,
    f: &Fields,
    locate: impl Fn(&str) -> (String, Option<usize>),
) -> Result<(), CalibError> {
    let fail = |n: &str, m: String| {
        let (key, l) = locate(n);
        Err(f.err(l, &key, m))
    };
    for (n, v) in [("fx", k.fx), ("fy", k.fy)] {
        if v <= 0.0 {
            return fail(n, format!("focal length {v} must be positive"));
        }
    }
    if !(0.5..=2.0).contains(&(k.fx / k.fy)) {
        return fail(
            "fy",
            format!(
                "fx / fy = {:.3}: pixels this far from square are not a camera (0.5..2 accepted)",
                k.fx / k.fy
            ),
        );
    }
    for (n, c, side) in [("cx", k.cx, k.width), ("cy", k.cy, k.height)] {
        if c < 0.0 || c > side as f64 {
            return fail(
                n,
                format!("principal point {c} lies outside the image ({side} pixels)"),
            );
        }
    }
    if fps <= 0.0 {
        return fail("fps", format!("frame rate {fps} must be positive"));
    }
    let side =
        (k.cx.max(k.width as f64 - k.cx) / k.fx).max(k.cy.max(k.height as f64 - k.cy) / k.fy);
    let max = k.theta_max();
    if k.theta_d(max) < side {
        return fail(
            "k1",
            format!(
                "the radius polynomial (k1 {}, k2 {}, k3 {}, k4 {}) folds back at {:.0} degrees, inside the image: not a lens",
                k.k1, k.k2, k.k3, k.k4, max.to_degrees()
            ),
        );
    }
    Ok(())
}

#[cfg(test)]
mod tests;
