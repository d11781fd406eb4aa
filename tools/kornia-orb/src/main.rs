//! `kornia-orb-measure IMAGE... [--n 1000] [--repeat R]`: kornia-imgproc ORB, one rayon thread,
//! printing the same JSON as `sdslam features --json`.

use std::time::Instant;

use kornia_image::{Image, ImageSize};
use kornia_imgproc::features::OrbDetector;

fn main() {
    let mut args: Vec<String> = std::env::args().skip(1).collect();
    let mut take = |flag: &str, default: usize| -> usize {
        match args.iter().position(|a| a == flag) {
            Some(i) => {
                let v = args.remove(i + 1).parse().expect("number");
                args.remove(i);
                v
            }
            None => default,
        }
    };
    let n = take("--n", 1000);
    let repeat = take("--repeat", 10);
    let mut det = OrbDetector::new();
    det.n_keypoints = n;
    let (mut times, mut counts) = (Vec::new(), Vec::new());
    for p in &args {
        let img = image::open(p).expect("image").to_luma8();
        let size = ImageSize { width: img.width() as usize, height: img.height() as usize };
        let im = Image::<u8, 1>::new(size, img.into_raw()).expect("kornia image");
        for _ in 0..repeat {
            let t = Instant::now();
            let f = det.detect_and_extract_u8(&im).expect("orb");
            times.push(t.elapsed().as_secs_f64() * 1e3);
            counts.push(f.len() as f64);
        }
    }
    times.sort_by(|a, b| a.total_cmp(b));
    counts.sort_by(|a, b| a.total_cmp(b));
    println!("{{\"median_ms\": {:.4}, \"features\": {}, \"images\": {}, \"repeat\": {repeat}}}", times[times.len() / 2], counts[counts.len() / 2], args.len());
}
