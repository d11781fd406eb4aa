//! Vocabulary: DBoW2 text import on the shared fixture, binary round trip and refusal of bad
//! files, and training that makes views of the same place score higher than other places.

mod common;

use common::problems::Rng;
use sdslam::features::Descriptor;
use sdslam::place_recognition::{
    decode_vocabulary, encode_vocabulary, l1_score, parse_dbow2_text, train, KeyFrameDatabase,
    TrainConfig, VocabularyFormatError,
};

#[test]
fn imports_the_orbslam_text_vocabulary_and_round_trips_in_binary() {
    let Some(data) = common::shared_data() else {
        return;
    };
    let text = std::fs::read_to_string(data.join("vocab/wangzheqie_voc_orbslam2_txt.txt")).unwrap();
    let v = parse_dbow2_text(&text).unwrap();
    assert_eq!((v.k, v.levels), (9, 3));
    assert_eq!(v.nodes.len(), 521);
    assert!(v.n_words() > 300, "{}", v.n_words());
    assert!(v.nodes.iter().skip(1).all(|n| n.children.len() <= 9));
    let bytes = encode_vocabulary(&v);
    let back = decode_vocabulary(&bytes).unwrap();
    assert_eq!(back, v);
    // The transform is the same through either copy.
    let mut rng = Rng(3);
    let ds: Vec<Descriptor> = (0..200)
        .map(|_| {
            [
                rng.f().to_bits(),
                rng.f().to_bits(),
                rng.f().to_bits(),
                rng.f().to_bits(),
            ]
        })
        .collect();
    assert_eq!(v.transform(&ds, 1), back.transform(&ds, 1));
    // A text line with a bad field names its line.
    let broken = text.replacen("0 1 ", "0 7 ", 1);
    if let Err(VocabularyFormatError::Text { line, .. }) = parse_dbow2_text(&broken) {
        assert!(line > 1);
    }
    let e = parse_dbow2_text("9 3 0 0\n0 0 1 2 3\n").unwrap_err();
    assert!(e.to_string().contains("line 2"), "{e}");
}

#[test]
fn binary_format_refuses_truncated_corrupted_and_foreign_files() {
    let v = small_trained();
    let bytes = encode_vocabulary(&v);
    assert!(matches!(
        decode_vocabulary(&bytes[..bytes.len() - 5]),
        Err(VocabularyFormatError::Truncated(_))
    ));
    let mut flipped = bytes.clone();
    flipped[40] ^= 0x10;
    assert_eq!(
        decode_vocabulary(&flipped),
        Err(VocabularyFormatError::Checksum)
    );
    let mut version = bytes.clone();
    version[8] = 99;
    assert!(matches!(
        decode_vocabulary(&version),
        Err(VocabularyFormatError::Version { found: 99, .. })
    ));
    assert_eq!(
        decode_vocabulary(b"ORBvoc.txt 10 6"),
        Err(VocabularyFormatError::Magic)
    );
    assert_eq!(decode_vocabulary(&[]), Err(VocabularyFormatError::Magic));
}

/// Descriptors of `places` places: each place has 60 base descriptors; a view flips ~8% of bits.
fn views(places: usize, views_per_place: usize, seed: u64) -> Vec<(usize, Vec<Descriptor>)> {
    let mut rng = Rng(seed);
    let bases: Vec<Vec<Descriptor>> = (0..places)
        .map(|_| {
            (0..60)
                .map(|_| {
                    [
                        rng.f().to_bits() ^ (rng.f().to_bits() << 7),
                        rng.f().to_bits(),
                        rng.f().to_bits() >> 3,
                        rng.f().to_bits() << 11,
                    ]
                })
                .collect()
        })
        .collect();
    let mut out = Vec::new();
    for (p, base) in bases.iter().enumerate() {
        for _ in 0..views_per_place {
            let v: Vec<Descriptor> = base
                .iter()
                .map(|d| {
                    let mut d = *d;
                    for _ in 0..20 {
                        let b = (rng.f() * 256.0) as usize % 256;
                        d[b >> 6] ^= 1 << (b & 63);
                    }
                    d
                })
                .collect();
            out.push((p, v));
        }
    }
    out
}

fn small_trained() -> sdslam::place_recognition::Vocabulary {
    let imgs: Vec<Vec<Descriptor>> = views(10, 2, 1).into_iter().map(|(_, v)| v).collect();
    train(
        &imgs,
        &TrainConfig {
            k: 6,
            levels: 3,
            iterations: 6,
            seed: 1,
        },
    )
    .unwrap()
}

/// A k = 10, L = 3 vocabulary trained on 3 views of each of 20 simulated places.
fn trained_on_20_places() -> sdslam::place_recognition::Vocabulary {
    let training: Vec<Vec<Descriptor>> = views(20, 3, 5).into_iter().map(|(_, v)| v).collect();
    train(
        &training,
        &TrainConfig {
            k: 10,
            levels: 3,
            iterations: 8,
            seed: 2,
        },
    )
    .unwrap()
}

#[test]
fn trained_vocabulary_recognises_places() {
    let v = trained_on_20_places();
    assert!(v.n_words() > 100, "{}", v.n_words());
    // New views of the same places (same seed: same bases, new noise draws).
    let test = views(20, 4, 5);
    let bows: Vec<(usize, Vec<(u32, f32)>)> = test
        .iter()
        .map(|(p, d)| (*p, v.transform(d, 1).0))
        .collect();
    let mut correct = 0;
    for (i, (p, b)) in bows.iter().enumerate() {
        let best = bows
            .iter()
            .enumerate()
            .filter(|(j, _)| *j != i)
            .max_by(|x, y| l1_score(b, &x.1 .1).total_cmp(&l1_score(b, &y.1 .1)))
            .map(|(_, (q, _))| *q);
        correct += (best == Some(*p)) as usize;
    }
    assert!(
        correct as f64 >= 0.95 * bows.len() as f64,
        "{correct}/{}",
        bows.len()
    );
    // Scores are in [0, 1] and a vector scores 1 with itself.
    assert!((l1_score(&bows[0].1, &bows[0].1) - 1.0).abs() < 1e-5);
}

#[test]
fn keyframe_database_returns_the_same_place_first_and_forgets_removed_keyframes() {
    let v = trained_on_20_places();
    let mut db = KeyFrameDatabase::new(v.n_words());
    // Keyframe key = place * 10 + view.
    for (i, (p, d)) in views(20, 2, 5).iter().enumerate() {
        db.add((*p * 10 + i % 2) as u32, &v.transform(d, 1).0);
    }
    assert_eq!(db.len(), 40);
    let queries = views(20, 3, 5);
    let mut correct = 0;
    for (p, d) in &queries {
        let r = db.query(&v.transform(d, 1).0, 0.0, 5, |_| false);
        correct += r.first().is_some_and(|&(k, _)| k as usize / 10 == *p) as usize;
        assert!(r.windows(2).all(|w| w[0].1 >= w[1].1));
    }
    assert!(
        correct as f64 >= 0.95 * queries.len() as f64,
        "{correct}/{}",
        queries.len()
    );
    // Excluded and removed keyframes are never returned.
    let q = v.transform(&queries[0].1, 1).0;
    let r = db.query(&q, 0.0, 40, |k| k / 10 == 0);
    assert!(r.iter().all(|&(k, _)| k / 10 != 0));
    db.remove(0);
    db.remove(1);
    assert!(db
        .query(&q, 0.0, 40, |_| false)
        .iter()
        .all(|&(k, _)| k != 0 && k != 1));
    assert_eq!(db.len(), 38);
}
