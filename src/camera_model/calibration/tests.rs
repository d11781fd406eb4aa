use super::*;

const FISHEYE: &str = "%YAML:1.0\nCamera.type: \"KannalaBrandt8\"\nCamera1.fx: 190.97\nCamera1.fy: 190.97\nCamera1.cx: 254.93\nCamera1.cy: 256.90\nCamera1.k1: 0.0034823894022493434\nCamera1.k2: 0.0007150348452162257\nCamera1.k3: -0.0020532361418706202\nCamera1.k4: 0.00020293673591811182\nCamera.width: 512\nCamera.height: 512\nCamera.fps: 20\n";

#[test]
fn parses_orbslam3_kannala_brandt_and_writes_it_back() {
    let c = Calibration::parse(FISHEYE, "tumvi.yaml").unwrap();
    let k = c.fisheye.unwrap();
    assert_eq!((k.fx, k.k4, k.width), (190.97, 0.00020293673591811182, 512));
    // The pinhole view: same size and principal point, 90 degrees across.
    assert_eq!((c.camera.width, c.camera.cx), (512, 254.93));
    assert!(c.camera.is_distortion_free());
    assert!((c.camera.fx - (512.0 - 254.93 - 0.5)).abs() < 1e-9);
    let wide = Calibration::parse(&format!("{FISHEYE}Camera.viewFov: 120\n"), "w.yaml").unwrap();
    assert!((wide.camera.fx * 3f64.sqrt() - (512.0 - 254.93 - 0.5)).abs() < 1e-9);
    let again = Calibration::parse(&wide.to_orbslam_yaml(""), "again.yaml").unwrap();
    assert!((again.camera.fx - wide.camera.fx).abs() < 1e-9);
    let again = Calibration::parse(&c.to_orbslam_yaml("round trip"), "again.yaml").unwrap();
    assert_eq!(again, c);
}

#[test]
fn coefficients_of_the_other_model_are_refused() {
    let bad = FISHEYE.replace("Camera1.k4", "Camera1.p1");
    let e = Calibration::parse(&bad, "f.yaml").unwrap_err().to_string();
    assert!(
        e.contains("Camera1.p1") && e.contains("KannalaBrandt8"),
        "{e}"
    );
    let e = Calibration::parse(&format!("{DESK}Camera.k4: 0.1\n"), "p.yaml")
        .unwrap_err()
        .to_string();
    assert!(e.contains("Camera.k4"), "{e}");
    let folds = FISHEYE.replace("Camera1.k1: 0.0034823894022493434", "Camera1.k1: -0.3");
    let e = Calibration::parse(&folds, "f.yaml")
        .unwrap_err()
        .to_string();
    assert!(e.contains("folds back"), "{e}");
}

const DESK: &str = "%YAML:1.0\n# Pinhole\nCamera.type: \"PinHole\"\nCamera.fx: 520.0\nCamera.fy: 520.0\nCamera.cx: 319.5\nCamera.cy: 239.5\nCamera.k1: 0.0\nCamera.k2: 0.0\nCamera.p1: 0.0\nCamera.p2: 0.0\nCamera.width: 640\nCamera.height: 480\nCamera.fps: 30.0\nCamera.RGB: 1\nDepthMapFactor: 5000.0\n";

#[test]
fn parses_orbslam_file() {
    let c = Calibration::parse(DESK, "camera.yaml").unwrap();
    assert_eq!(c.camera.fx, 520.0);
    assert_eq!(c.camera.width, 640);
    assert_eq!(c.fps, 30.0);
    assert!(c.camera.is_distortion_free());
}

#[test]
fn round_trips_through_writer() {
    let c = Calibration::parse(DESK, "a").unwrap();
    let d = Calibration::parse(&c.to_orbslam_yaml("test"), "b").unwrap();
    assert_eq!(c, d);
}

fn err_of(text: &str) -> String {
    Calibration::parse(text, "cam.yaml")
        .unwrap_err()
        .to_string()
}

#[test]
fn unknown_key_names_line_and_field() {
    let e = err_of(&format!("{DESK}Camera.fz: 3\n"));
    assert!(
        e.contains("cam.yaml:17") && e.contains("Camera.fz") && e.contains("unknown"),
        "{e}"
    );
}

#[test]
fn missing_field_is_named() {
    let e = err_of(&DESK.replace("Camera.fy: 520.0\n", ""));
    assert!(e.contains("Camera.fy") && e.contains("missing"), "{e}");
}

#[test]
fn non_positive_focal_and_nan_are_rejected() {
    let e = err_of(&DESK.replace("Camera.fx: 520.0", "Camera.fx: -1"));
    assert!(
        e.contains("cam.yaml:4") && e.contains("Camera.fx") && e.contains("positive"),
        "{e}"
    );
    let e = err_of(&DESK.replace("Camera.fx: 520.0", "Camera.fx: 0"));
    assert!(e.contains("positive"), "{e}");
    let e = err_of(&DESK.replace("Camera.k1: 0.0", "Camera.k1: .nan"));
    assert!(e.contains("Camera.k1") && e.contains(":8"), "{e}");
    let e = err_of(&DESK.replace("Camera.k1: 0.0", "Camera.k1: NaN"));
    assert!(e.contains("Camera.k1") && e.contains("finite"), "{e}");
    let e = err_of(&DESK.replace("Camera.width: 640", "Camera.width: 64.5"));
    assert!(e.contains("Camera.width"), "{e}");
}

#[test]
fn what_cannot_be_a_camera_is_refused() {
    for (from, to, field, why) in [
        (
            "Camera.fx: 520.0",
            "Camera.fx: 1e30",
            "Camera.fx",
            "field of view",
        ),
        (
            "Camera.fx: 520.0",
            "Camera.fx: 1e-30",
            "Camera.fx",
            "field of view",
        ),
        (
            "Camera.fy: 520.0",
            "Camera.fy: 0.001",
            "Camera.fy",
            "field of view",
        ),
        (
            "Camera.fy: 520.0",
            "Camera.fy: 2000.0",
            "Camera.fy",
            "square",
        ),
        ("Camera.k1: 0.0", "Camera.k1: 50.0", "Camera.k1", "corners"),
        (
            "Camera.k1: 0.0",
            "Camera.k1: -3.0",
            "Camera.k1",
            "folds over",
        ),
    ] {
        let e = err_of(&DESK.replace(from, to));
        assert!(e.contains(field) && e.contains(why), "{to}: {e}");
    }
    // A real wide-angle lens (EuRoC's cam0 distortion) is accepted.
    let ok = DESK
        .replace("Camera.k1: 0.0", "Camera.k1: -0.2834")
        .replace("Camera.k2: 0.0", "Camera.k2: 0.0739");
    Calibration::parse(&ok, "cam.yaml").unwrap();
}

#[test]
fn image_size_mismatch_is_clear() {
    let c = Calibration::parse(DESK, "a").unwrap();
    let e = c
        .check_image_size(752, 480, "calib/x.yaml")
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("calib/x.yaml") && e.contains("640x480") && e.contains("752x480"),
        "{e}"
    );
}

const EUROC: &str = "%YAML:1.0\nsensor_type: camera\ncomment: VI-Sensor cam0 (MT9M034)\nT_BS:\n  cols: 4\n  rows: 4\n  data: [0.0148655429818, -0.999880929698, 0.00414029679422, -0.0216401454975,\n         0.999557249008, 0.0149672133247, 0.025715529948, -0.064676986768,\n        -0.0257744366974, 0.00375618835797, 0.999660727178, 0.00981073058949,\n         0.0, 0.0, 0.0, 1.0]\nrate_hz: 20\nresolution: [752, 480]\ncamera_model: pinhole\nintrinsics: [458.654, 457.296, 367.215, 248.375] #fu, fv, cu, cv\ndistortion_model: radial-tangential\ndistortion_coefficients: [-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05]\n";

#[test]
fn parses_euroc_sensor_yaml() {
    let c = Calibration::parse(EUROC, "sensor.yaml").unwrap();
    assert_eq!(c.camera.fx, 458.654);
    assert_eq!(c.camera.k1, -0.28340811);
    assert_eq!((c.camera.width, c.camera.height), (752, 480));
    assert_eq!(c.fps, 20.0);
}

#[test]
fn euroc_errors_name_fields() {
    let e = Calibration::parse(
        &EUROC.replace("[458.654, 457.296, 367.215, 248.375]", "[458.654, 457.296]"),
        "s.yaml",
    )
    .unwrap_err()
    .to_string();
    assert!(e.contains("intrinsics") && e.contains("s.yaml:14"), "{e}");
    let e = Calibration::parse(&EUROC.replace("pinhole", "omni"), "s.yaml")
        .unwrap_err()
        .to_string();
    assert!(e.contains("camera_model"), "{e}");
}
