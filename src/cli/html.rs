//! `sdslam eval report RUN`: one self-contained page summarising a run (tables from
//! report.json, ATE and RPE against RUN/groundtruth.txt when present, the run's pictures).

use std::fmt::Write as _;
use std::path::Path;

use sdslam::eval::{ate, rpe};
use sdslam::io::{read_tum_trajectory, write_atomic};
use sdslam::{Error, Result};

fn esc(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
}

fn cell(v: &serde_json::Value) -> String {
    match v {
        serde_json::Value::Number(n) => match n.as_f64() {
            Some(f) if f.fract() != 0.0 => format!("{f:.3}"),
            _ => n.to_string(),
        },
        serde_json::Value::Null => "-".into(),
        serde_json::Value::String(s) => esc(s),
        other => esc(&other.to_string()),
    }
}

pub fn write_report(run: &Path) -> Result<()> {
    let rp = run.join("report.json");
    let text = sdslam_camera::capped::read_text_capped(&rp, sdslam_camera::capped::SETTINGS_CAP)
        .map_err(|e| Error::io(&rp, e))?;
    let r: serde_json::Value = serde_json::from_str(&text)
        .map_err(|e| Error::Invalid(format!("{}: not a run report: {e}", rp.display())))?;
    let obj = r
        .as_object()
        .ok_or_else(|| Error::Invalid(format!("{}: not a run report", rp.display())))?;
    let mut h = String::new();
    let _ = write!(
        h,
        "<!doctype html><html><head><meta charset=\"utf-8\"><title>sdslam run {}</title><style>\
         body{{font-family:sans-serif;max-width:1250px;margin:2em auto;color:#222}}\
         table{{border-collapse:collapse;margin:1em 0}}td,th{{border:1px solid #ccc;padding:3px 8px;text-align:right}}\
         th{{background:#f3f3f3}}td:first-child,th:first-child{{text-align:left}}img{{max-width:100%;border:1px solid #ddd;margin:.5em 0}}\
         </style></head><body><h1>sdslam run</h1><p>{} &middot; source {} &middot; sdslam {}</p>",
        esc(&run.display().to_string()),
        esc(&run.display().to_string()),
        cell(&r["source"]),
        cell(&r["sdslam_version"])
    );
    if let Some(s) = obj.get("stopped_early").and_then(|v| v.as_str()) {
        let _ = write!(h, "<p><b>Stopped early:</b> {}</p>", esc(s));
    }
    h.push_str("<h2>Run</h2><table><tr><th>figure</th><th>value</th></tr>");
    for (k, v) in obj {
        if !v.is_object() && k != "source" && k != "sdslam_version" {
            let _ = write!(h, "<tr><td>{}</td><td>{}</td></tr>", esc(k), cell(v));
        }
    }
    h.push_str("</table>");
    // Trajectory accuracy, when the run folder has the ground truth.
    let gt_path = run.join("groundtruth.txt");
    if gt_path.is_file() {
        let gt = read_tum_trajectory(&gt_path)?;
        h.push_str("<h2>Trajectory accuracy (Sim3-aligned)</h2><table><tr><th>trajectory</th><th>matched</th><th>ATE rmse (cm)</th><th>RPE 1 s trans rmse (cm)</th><th>RPE 1 s rot rmse (deg)</th></tr>");
        for name in ["keyframes.txt", "trajectory.txt"] {
            let p = run.join(name);
            if !p.is_file() {
                continue;
            }
            let est = read_tum_trajectory(&p)?;
            let a = ate(&gt, &est, 0.02, true);
            let e = rpe(&gt, &est, 0.02, 1.0, true);
            let _ = write!(
                h,
                "<tr><td>{name}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td></tr>",
                a.as_ref().map_or("-".into(), |a| a.matched.to_string()),
                a.as_ref()
                    .map_or("-".into(), |a| format!("{:.3}", a.rmse_m * 100.0)),
                e.as_ref()
                    .map_or("-".into(), |e| format!("{:.3}", e.trans_rmse * 100.0)),
                e.as_ref()
                    .map_or("-".into(), |e| format!("{:.3}", e.rot_rmse_deg)),
            );
        }
        h.push_str("</table>");
    }
    if let Some(acc) = obj.get("semidense_accuracy").and_then(|v| v.as_object()) {
        h.push_str("<h2>Semi-dense accuracy</h2><table><tr><th>figure</th><th>value</th></tr>");
        for (k, v) in acc {
            let _ = write!(h, "<tr><td>{}</td><td>{}</td></tr>", esc(k), cell(v));
        }
        h.push_str("</table>");
    }
    if let Some(t) = obj.get("timing_ms").and_then(|v| v.as_object()) {
        h.push_str("<h2>Timing (ms)</h2><table><tr><th>stage</th><th>p50</th><th>p90</th><th>p99</th><th>max</th><th>count</th></tr>");
        for (k, v) in t {
            let _ = write!(
                h,
                "<tr><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td></tr>",
                esc(k),
                cell(&v["p50"]),
                cell(&v["p90"]),
                cell(&v["p99"]),
                cell(&v["max"]),
                cell(&v["count"])
            );
        }
        h.push_str("</table>");
    }
    h.push_str("<h2>Pictures</h2>");
    for img in ["trajectory.png", "cloud.png", "timing.png"] {
        if run.join(img).is_file() {
            let _ = write!(h, "<p><img src=\"{img}\" alt=\"{img}\"></p>");
        }
    }
    h.push_str("</body></html>\n");
    let out = run.join("report.html");
    write_atomic(&out, h.as_bytes())?;
    out!("{}", out.display());
    Ok(())
}
