//! `sdslam features`: time ORB extraction on images, one thread, for comparison with other
//! extractors on the same files.

use std::path::PathBuf;
use std::time::Instant;

use clap::Args;

use sdslam::camera::decode::ImageDecoderBuf;
use sdslam::camera::Frame;
use sdslam::config::OrbConfig;
use sdslam::features::{Features, OrbExtractor};
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
    let cfg = OrbConfig {
        n_features: a.n,
        ..OrbConfig::default()
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
    if a.json {
        println!("{{\"median_ms\": {mt:.4}, \"features\": {mc}, \"images\": {}, \"repeat\": {}}}", a.images.len(), a.repeat);
    } else {
        println!("{} images x {} runs: median {mt:.3} ms per extraction, median {mc} features", a.images.len(), a.repeat);
    }
    Ok(())
}
