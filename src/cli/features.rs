//! `sdslam features`: time ORB extraction on images, one thread, for comparison with other
//! extractors on the same files.

use std::path::PathBuf;
use std::time::Instant;

use clap::Args;

use sdslam::camera::decode::ImageDecoderBuf;
use sdslam::camera::Frame;
use sdslam::config::OrbConfig;
use sdslam::eval::orb_quality::warp_quality;
use sdslam::features::{Features, OrbExtractor};
use sdslam::image::warp::warp_perspective;
use sdslam::{Error, Result};

#[derive(Args, Debug)]
pub struct FeaturesArgs {
    /// Images (PNG or JPEG; colour is converted to grey).
    #[arg(required = true)]
    images: Vec<PathBuf>,
    /// Features per image.
    #[arg(long, default_value_t = 1000)]
    n: usize,
    /// Extractions per image.
    #[arg(long, default_value_t = 10)]
    repeat: usize,
    /// Print one JSON object (`median_ms`, `features`).
    #[arg(long)]
    json: bool,
    /// Also measure repeatability and matching score against each image warped by this
    /// homography (9 numbers, row-major, mapping source to warped pixels).
    #[arg(long, allow_hyphen_values = true)]
    warp: Option<String>,
    /// TOML configuration whose `[orb]` section is used (threads are forced to 1).
    #[arg(long)]
    config: Option<PathBuf>,
}

fn median(v: &mut [f64]) -> f64 {
    v.sort_by(|a, b| a.total_cmp(b));
    if v.is_empty() {
        0.0
    } else if v.len() % 2 == 1 {
        v[v.len() / 2]
    } else {
        0.5 * (v[v.len() / 2 - 1] + v[v.len() / 2])
    }
}

pub fn features(a: FeaturesArgs) -> Result<()> {
    if a.repeat == 0 || a.n == 0 {
        return Err(Error::Invalid("--repeat and --n must be positive".into()));
    }
    if a.n > sdslam::config::MAX_FEATURES {
        return Err(Error::Invalid(format!(
            "--n {}: at most {} features",
            a.n,
            sdslam::config::MAX_FEATURES
        )));
    }
    // One thread: the figure compared with other extractors is single-threaded.
    let base = match &a.config {
        Some(p) => sdslam::config::Config::load(p)?.orb,
        None => OrbConfig::default(),
    };
    let cfg = OrbConfig {
        n_features: a.n,
        threads: 1,
        ..base
    };
    let mut dec = ImageDecoderBuf::new();
    let mut frame = Frame::new(0, 0);
    let mut ex: Option<OrbExtractor> = None;
    let mut feats = Features::with_capacity(a.n * 2);
    let (mut times, mut counts) = (Vec::new(), Vec::new());
    for p in &a.images {
        dec.read_file(p, None, &mut frame)?;
        let (w, h) = (frame.width as usize, frame.height as usize);
        let e = match &mut ex {
            Some(e) if e.pyramid().levels[0].width == w && e.pyramid().levels[0].height == h => e,
            _ => ex.insert(OrbExtractor::new(w, h, &cfg)),
        };
        for _ in 0..a.repeat {
            let t = Instant::now();
            e.extract(&frame.gray, None, &mut feats);
            times.push(t.elapsed().as_secs_f64() * 1e3);
            counts.push(feats.len() as f64);
        }
    }
    let (mt, mc) = (median(&mut times), median(&mut counts));
    let quality = match &a.warp {
        Some(h) => {
            let h: Vec<f64> = h
                .split(',')
                .map(|v| v.trim().parse::<f64>().ok().filter(|x| x.is_finite()))
                .collect::<Option<_>>()
                .filter(|v: &Vec<f64>| v.len() == 9)
                .ok_or_else(|| {
                    Error::Invalid(format!("--warp {h:?}: expected 9 comma-separated numbers"))
                })?;
            Some(warp_quality_over(&a.images, &h, &cfg)?)
        }
        None => None,
    };
    if a.json {
        let q = quality
            .map(|(r, m)| format!(", \"repeatability\": {r:.4}, \"matching_score\": {m:.4}"))
            .unwrap_or_default();
        out!(
            "{{\"median_ms\": {mt:.4}, \"features\": {mc}, \"images\": {}, \"repeat\": {}{q}}}",
            a.images.len(),
            a.repeat
        );
    } else {
        out!(
            "{} images x {} runs: median {mt:.3} ms per extraction, median {mc} features",
            a.images.len(),
            a.repeat
        );
        if let Some((r, m)) = quality {
            out!("under the homography: repeatability {r:.3}, matching score {m:.3} (mean over images, 2.5 px)");
        }
    }
    Ok(())
}

/// Mean repeatability and matching score of each image against its warp by `h`.
fn warp_quality_over(images: &[PathBuf], h: &[f64], cfg: &OrbConfig) -> Result<(f64, f64)> {
    let hm = nalgebra::Matrix3::from_row_slice(h);
    let mut dec = ImageDecoderBuf::new();
    let mut frame = Frame::new(0, 0);
    let (mut rs, mut ms) = (0.0, 0.0);
    for p in images {
        dec.read_file(p, None, &mut frame)?;
        let (w, hgt) = (frame.width as usize, frame.height as usize);
        let mut warped = vec![0u8; w * hgt];
        if !warp_perspective(&frame.gray, w, hgt, &hm, &mut warped) {
            return Err(Error::Invalid("--warp: the homography is singular".into()));
        }
        let mut ex = OrbExtractor::new(w, hgt, cfg);
        let (mut fa, mut fb) = (Features::default(), Features::default());
        ex.extract(&frame.gray, None, &mut fa);
        ex.extract(&warped, None, &mut fb);
        let q = warp_quality(&fa, &fb, &hm, w as f64, hgt as f64, 16.0, 2.5);
        rs += q.repeatability;
        ms += q.matching_score;
    }
    let n = images.len() as f64;
    Ok((rs / n, ms / n))
}
