//! Place recognition with a vocabulary tree of binary words (Gálvez-López & Tardós, 2012):
//! k-means++ training with Hamming distance and majority-bit centroids, tf-idf weights, L1
//! scoring, bag-of-words and feature vectors per image, an inverted-index keyframe database; a versioned, checksummed binary format
//! and an importer of DBoW2 text vocabularies (ORB-SLAM's `ORBvoc.txt` layout).

mod database;
mod dbow2;
mod format;
mod train;
mod vocabulary;

pub use database::KeyFrameDatabase;
pub use dbow2::parse_dbow2_text;
pub use format::{decode_vocabulary, encode_vocabulary, VocabularyFormatError, FORMAT_VERSION};
pub use train::{train, TrainConfig};
pub use vocabulary::{l1_score, BowVector, FeatureVector, Node, Vocabulary};
