//! Place recognition with a vocabulary tree of binary words (Gálvez-López & Tardós, 2012):
//! k-means++ training with Hamming distance and majority-bit centroids, tf-idf weights, L1
//! scoring, bag-of-words and feature vectors per image, an inverted-index keyframe database; a versioned, checksummed binary format
//! and an importer of DBoW2 text vocabularies (ORB-SLAM's `ORBvoc.txt` layout).

mod database;
mod dbow2;
mod format;
mod index;
mod train;
mod vocabulary;

pub use database::KeyFrameDatabase;
pub use dbow2::parse_dbow2_text;
pub use format::{decode_vocabulary, encode_vocabulary, VocabularyFormatError, FORMAT_VERSION};
pub use index::PlaceIndex;
pub use train::{train, TrainConfig};
pub use vocabulary::{l1_score, BowVector, FeatureVector, Node, Vocabulary};

/// The vocabulary shipped with the crate, used when none is given: 9,514 words (k = 10, L = 4)
/// trained on every 5th frame of the built-in synthetic sequence and the 30 real EuRoC frames
/// of `euroc_v101_micro` (66 images), by
/// `sdslam synth --out /tmp/syn --frames 300 --depth-every 0 &&
///  sdslam vocab train /tmp/syn ../shared/data/euroc_v101_micro --k 10 --levels 4 --every 5
///  --out src/place_recognition/default_vocabulary.sdsvoc`.
/// Small and fast to load; for large real environments pass ORB-SLAM's `ORBvoc.txt` (imported
/// with `sdslam vocab import`).
pub fn default_vocabulary() -> Result<Vocabulary, VocabularyFormatError> {
    decode_vocabulary(include_bytes!("default_vocabulary.sdsvoc"))
}

#[cfg(test)]
mod default_tests {
    #[test]
    fn the_shipped_vocabulary_loads() {
        let v = super::default_vocabulary().unwrap();
        assert_eq!(v.n_words(), 9514);
    }
}
