//! Pictures of a run, next to its text outputs: `trajectory.png` (top and side views of the
//! keyframe trajectory, with the ground truth aligned by Sim3 when there is one),
//! `cloud.png` (top view of the semi-dense cloud in its colours) and `timing.png` (per-frame
//! tracking latency against the deadline). Drawn with `plotters` into a buffer, written as PNG
//! atomically; the font is embedded (DejaVu Sans), so no system fonts are needed.

use std::path::Path;
use std::sync::Once;

use plotters::prelude::*;

use sdslam::eval::TimedPose;
use sdslam::geometry::Sim3;
use sdslam::io::{write_rgb_png, CloudPoint};
use sdslam::{Error, Result};

static FONT: &[u8] = include_bytes!("assets/DejaVuSans.ttf");

fn font() {
    static ONCE: Once = Once::new();
    ONCE.call_once(|| {
        let _ = plotters::style::register_font("sans-serif", FontStyle::Normal, FONT);
    });
}

fn plot_err(path: &Path, e: impl std::fmt::Display) -> Error {
    Error::Invalid(format!("{}: cannot draw: {e}", path.display()))
}

/// Draws into an RGB buffer with `draw`, then writes it as PNG.
fn render(
    path: &Path,
    (w, h): (u32, u32),
    draw: impl FnOnce(
        DrawingArea<BitMapBackend, plotters::coord::Shift>,
    ) -> std::result::Result<(), String>,
) -> Result<()> {
    font();
    let mut buf = vec![255u8; (w * h * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area();
        root.fill(&WHITE).map_err(|e| plot_err(path, e))?;
        draw(root.clone()).map_err(|e| plot_err(path, e))?;
        root.present().map_err(|e| plot_err(path, e))?;
    }
    write_rgb_png(path, w, h, &buf)
}

/// Range of `v` with a margin, never empty.
fn range(v: impl Iterator<Item = f64>) -> (f64, f64) {
    let (mut lo, mut hi) = (f64::MAX, f64::MIN);
    for x in v.filter(|x| x.is_finite()) {
        lo = lo.min(x);
        hi = hi.max(x);
    }
    if lo > hi {
        return (-1.0, 1.0);
    }
    let pad = ((hi - lo) * 0.05).max(1e-3);
    (lo - pad, hi + pad)
}

/// Keyframe trajectory, top (x-z) and side (x-y) views; with ground truth, the estimate is
/// brought into its frame by `alignment` and the ATE goes in the title.
pub fn trajectory(
    path: &Path,
    keyframes: &[TimedPose],
    gt: Option<(&[TimedPose], &Sim3, f64)>,
) -> Result<()> {
    let est: Vec<[f64; 3]> = keyframes
        .iter()
        .map(|p| {
            let c = p.t_wc.position();
            let c = match gt {
                Some((_, a, _)) => a.transform(&c),
                None => c,
            };
            [c.x, c.y, c.z]
        })
        .collect();
    let truth: Vec<[f64; 3]> = gt
        .map(|(g, _, _)| {
            g.iter()
                .map(|p| p.t_wc.position())
                .map(|c| [c.x, c.y, c.z])
                .collect()
        })
        .unwrap_or_default();
    let title = match gt {
        Some((_, _, ate)) => format!(
            "keyframe trajectory ({} keyframes), ATE {:.2} cm after Sim3 alignment",
            est.len(),
            ate * 100.0
        ),
        None => format!(
            "keyframe trajectory ({} keyframes), no ground truth",
            est.len()
        ),
    };
    render(path, (1200, 600), |root| {
        let root = root
            .titled(&title, ("sans-serif", 22))
            .map_err(|e| e.to_string())?;
        let panels = root.split_evenly((1, 2));
        for (panel, (axis, name)) in panels
            .iter()
            .zip([(2usize, "top view: x / z"), (1usize, "side view: x / y")])
        {
            let all = est.iter().chain(&truth);
            let (x0, x1) = range(all.clone().map(|p| p[0]));
            let (y0, y1) = range(all.map(|p| p[axis]));
            let mut chart = ChartBuilder::on(panel)
                .caption(name, ("sans-serif", 16))
                .margin(12)
                .x_label_area_size(30)
                .y_label_area_size(50)
                .build_cartesian_2d(x0..x1, y0..y1)
                .map_err(|e| e.to_string())?;
            chart
                .configure_mesh()
                .light_line_style(WHITE.mix(0.0))
                .draw()
                .map_err(|e| e.to_string())?;
            if !truth.is_empty() {
                chart
                    .draw_series(LineSeries::new(
                        truth.iter().map(|p| (p[0], p[axis])),
                        BLACK.mix(0.6).stroke_width(2),
                    ))
                    .map_err(|e| e.to_string())?
                    .label("ground truth")
                    .legend(|(x, y)| PathElement::new([(x, y), (x + 20, y)], BLACK));
            }
            chart
                .draw_series(LineSeries::new(
                    est.iter().map(|p| (p[0], p[axis])),
                    RED.stroke_width(2),
                ))
                .map_err(|e| e.to_string())?
                .label("sdslam keyframes")
                .legend(|(x, y)| PathElement::new([(x, y), (x + 20, y)], RED));
            chart
                .draw_series(
                    est.iter()
                        .map(|p| Circle::new((p[0], p[axis]), 2, RED.filled())),
                )
                .map_err(|e| e.to_string())?;
            chart
                .configure_series_labels()
                .background_style(WHITE.mix(0.8))
                .border_style(BLACK)
                .draw()
                .map_err(|e| e.to_string())?;
        }
        Ok(())
    })
}

/// Top view (x-z) of the cloud in its image colours, at most 300,000 points (evenly thinned).
pub fn cloud(path: &Path, points: &[CloudPoint]) -> Result<()> {
    let step = (points.len() / 300_000).max(1);
    let pts: Vec<&CloudPoint> = points.iter().step_by(step).collect();
    // Robust extent: 1st to 99th percentile, so a few far points do not shrink the picture.
    let pct = |axis: usize| {
        let mut v: Vec<f64> = pts
            .iter()
            .map(|p| p.position[axis] as f64)
            .filter(|x| x.is_finite())
            .collect();
        v.sort_by(|a, b| a.total_cmp(b));
        if v.is_empty() {
            return (-1.0, 1.0);
        }
        let (a, b) = (v[v.len() / 100], v[(v.len() * 99) / 100]);
        let pad = ((b - a) * 0.05).max(1e-3);
        (a - pad, b + pad)
    };
    let ((x0, x1), (z0, z1)) = (pct(0), pct(2));
    let title = format!(
        "semi-dense cloud, top view (x / z): {} points{}",
        points.len(),
        if step > 1 {
            format!(", 1 in {step} drawn")
        } else {
            String::new()
        }
    );
    render(path, (1000, 1000), |root| {
        let mut chart = ChartBuilder::on(&root)
            .caption(&title, ("sans-serif", 20))
            .margin(12)
            .x_label_area_size(30)
            .y_label_area_size(50)
            .build_cartesian_2d(x0..x1, z0..z1)
            .map_err(|e| e.to_string())?;
        chart
            .configure_mesh()
            .disable_mesh()
            .draw()
            .map_err(|e| e.to_string())?;
        chart
            .draw_series(
                pts.iter()
                    .filter(|p| {
                        let (x, z) = (p.position[0] as f64, p.position[2] as f64);
                        x >= x0 && x <= x1 && z >= z0 && z <= z1
                    })
                    .map(|p| {
                        Pixel::new(
                            (p.position[0] as f64, p.position[2] as f64),
                            RGBColor(p.rgb[0], p.rgb[1], p.rgb[2]),
                        )
                    }),
            )
            .map_err(|e| e.to_string())?;
        Ok(())
    })
}

/// Tracking latency per frame with the deadline.
pub fn timing(path: &Path, latencies_ms: &[f32], deadline_ms: f64) -> Result<()> {
    let n = latencies_ms.len().max(1);
    let top = latencies_ms
        .iter()
        .copied()
        .fold(0.0f32, f32::max)
        .max(deadline_ms as f32) as f64
        * 1.1;
    let misses = latencies_ms
        .iter()
        .filter(|&&l| l as f64 > deadline_ms)
        .count();
    let title = format!(
        "tracking latency per frame: {misses} of {} over the {deadline_ms:.1} ms deadline",
        latencies_ms.len()
    );
    render(path, (1200, 500), |root| {
        let mut chart = ChartBuilder::on(&root)
            .caption(&title, ("sans-serif", 20))
            .margin(12)
            .x_label_area_size(35)
            .y_label_area_size(50)
            .build_cartesian_2d(0..n, 0.0..top.max(1.0))
            .map_err(|e| e.to_string())?;
        chart
            .configure_mesh()
            .x_desc("frame")
            .y_desc("ms")
            .draw()
            .map_err(|e| e.to_string())?;
        chart
            .draw_series(LineSeries::new(
                latencies_ms.iter().enumerate().map(|(i, &l)| (i, l as f64)),
                BLUE,
            ))
            .map_err(|e| e.to_string())?
            .label("arrival to pose")
            .legend(|(x, y)| PathElement::new([(x, y), (x + 20, y)], BLUE));
        chart
            .draw_series(LineSeries::new(
                [(0, deadline_ms), (n, deadline_ms)],
                RED.stroke_width(2),
            ))
            .map_err(|e| e.to_string())?
            .label("deadline")
            .legend(|(x, y)| PathElement::new([(x, y), (x + 20, y)], RED));
        chart
            .configure_series_labels()
            .background_style(WHITE.mix(0.8))
            .border_style(BLACK)
            .draw()
            .map_err(|e| e.to_string())?;
        Ok(())
    })
}
