//! `sdslam vocab`: train a vocabulary on images or sequences, or convert a DBoW2 text
//! vocabulary to sdslam's binary format.

use std::path::{Path, PathBuf};

use clap::{Args, Subcommand};

use sdslam::camera::decode::ImageDecoderBuf;
use sdslam::camera::{Frame, FrameSource, FrameStatus, ImageListSource};
use sdslam::config::OrbConfig;
use sdslam::features::{Descriptor, Features, OrbExtractor};
use sdslam::io::{load_vocabulary, save_vocabulary};
use sdslam::place_recognition::{train, TrainConfig};
use sdslam::{Error, Result};

#[derive(Subcommand, Debug)]
pub enum VocabCommand {
    /// Train on images and/or sequence folders (TUM, EuRoC, image folders).
    Train(TrainArgs),
    /// Convert a vocabulary (DBoW2 text, e.g. ORB-SLAM's ORBvoc.txt) to the binary format.
    Import {
        input: PathBuf,
        #[arg(long)]
        out: PathBuf,
    },
}

#[derive(Args, Debug)]
pub struct TrainArgs {
    /// Image files or sequence folders.
    #[arg(required = true)]
    sources: Vec<PathBuf>,
    #[arg(long, default_value_t = 10)]
    k: usize,
    #[arg(long, default_value_t = 4)]
    levels: usize,
    /// Use every Nth frame of sequences.
    #[arg(long, default_value_t = 5)]
    every: usize,
    #[arg(long)]
    out: PathBuf,
}

fn extract(
    gray: &[u8],
    w: u32,
    h: u32,
    ex: &mut Option<OrbExtractor>,
    feats: &mut Features,
) -> Vec<Descriptor> {
    let e = match ex {
        Some(e)
            if e.pyramid().levels[0].width == w as usize
                && e.pyramid().levels[0].height == h as usize =>
        {
            e
        }
        _ => ex.insert(OrbExtractor::new(
            w as usize,
            h as usize,
            &OrbConfig::default(),
        )),
    };
    e.extract(gray, None, feats);
    feats.descriptors.clone()
}

fn collect(
    path: &Path,
    every: usize,
    out: &mut Vec<Vec<Descriptor>>,
    ex: &mut Option<OrbExtractor>,
) -> Result<()> {
    let mut feats = Features::with_capacity(2000);
    let mut frame = Frame::new(0, 0);
    if path.is_dir() {
        let mut src = ImageListSource::open(path)?;
        let mut i = 0usize;
        loop {
            match src.next_frame(&mut frame)? {
                FrameStatus::End => break,
                FrameStatus::Skipped { .. } => {}
                FrameStatus::Ready => {
                    if i.is_multiple_of(every.max(1)) {
                        out.push(extract(
                            &frame.gray,
                            frame.width,
                            frame.height,
                            ex,
                            &mut feats,
                        ));
                    }
                }
            }
            i += 1;
        }
    } else {
        ImageDecoderBuf::new().read_file(path, None, &mut frame)?;
        out.push(extract(
            &frame.gray,
            frame.width,
            frame.height,
            ex,
            &mut feats,
        ));
    }
    Ok(())
}

pub fn vocab(cmd: VocabCommand) -> Result<()> {
    match cmd {
        VocabCommand::Import { input, out } => {
            let v = load_vocabulary(&input)?;
            save_vocabulary(&out, &v)?;
            out!(
                "{} words (k {}, L {}) written to {}",
                v.n_words(),
                v.k,
                v.levels,
                out.display()
            );
            Ok(())
        }
        VocabCommand::Train(a) => {
            if a.k < 2 || a.levels == 0 || a.levels > 8 {
                return Err(Error::Invalid(
                    "--k must be >= 2 and --levels in 1..=8".into(),
                ));
            }
            let mut images = Vec::new();
            let mut ex = None;
            for s in &a.sources {
                collect(s, a.every, &mut images, &mut ex)?;
            }
            let cfg = TrainConfig {
                k: a.k,
                levels: a.levels,
                ..TrainConfig::default()
            };
            let v = train(&images, &cfg)
                .ok_or_else(|| Error::Invalid("no descriptors in the training sources".into()))?;
            save_vocabulary(&a.out, &v)?;
            out!(
                "trained on {} images: {} words (k {}, L {}), written to {}",
                images.len(),
                v.n_words(),
                v.k,
                v.levels,
                a.out.display()
            );
            Ok(())
        }
    }
}
