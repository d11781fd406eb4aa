//! sdslam's binary vocabulary format: compact, versioned and checksummed, so it loads fast and
//! a truncated, foreign or corrupted file is refused with a clear message.
//!
//! Layout (little endian): magic `SDSLVOC\0`, version u32, k u32, levels u32, node count u32,
//! then per node after the root: parent u32, is_leaf u8, 32 descriptor bytes, weight f32; then
//! the FNV-1a 64 checksum of everything before it.

use super::vocabulary::{Node, Vocabulary};

pub const FORMAT_VERSION: u32 = 1;
const MAGIC: &[u8; 8] = b"SDSLVOC\0";
const NODE_BYTES: usize = 4 + 1 + 32 + 4;

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum VocabularyFormatError {
    #[error("not an sdslam vocabulary (bad magic)")]
    Magic,
    #[error("vocabulary format version {found}, this build reads version {expected}")]
    Version { found: u32, expected: u32 },
    #[error("truncated: {0}")]
    Truncated(String),
    #[error("checksum mismatch (file corrupted)")]
    Checksum,
    #[error("invalid content: {0}")]
    Invalid(String),
    #[error("line {line}: {message}")]
    Text { line: usize, message: String },
}

fn fnv1a(bytes: &[u8]) -> u64 {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for &b in bytes {
        h ^= b as u64;
        h = h.wrapping_mul(0x0000_0100_0000_01b3);
    }
    h
}

pub fn encode_vocabulary(v: &Vocabulary) -> Vec<u8> {
    let mut out = Vec::with_capacity(28 + v.nodes.len() * NODE_BYTES + 8);
    out.extend_from_slice(MAGIC);
    for x in [
        FORMAT_VERSION,
        v.k as u32,
        v.levels as u32,
        v.nodes.len() as u32,
    ] {
        out.extend_from_slice(&x.to_le_bytes());
    }
    for n in v.nodes.iter().skip(1) {
        out.extend_from_slice(&n.parent.to_le_bytes());
        out.push(n.children.is_empty() as u8);
        for w in n.descriptor {
            out.extend_from_slice(&w.to_le_bytes());
        }
        out.extend_from_slice(&n.weight.to_le_bytes());
    }
    let c = fnv1a(&out);
    out.extend_from_slice(&c.to_le_bytes());
    out
}

pub fn decode_vocabulary(bytes: &[u8]) -> Result<Vocabulary, VocabularyFormatError> {
    if bytes.len() < 8 || &bytes[..8] != MAGIC {
        return Err(VocabularyFormatError::Magic);
    }
    if bytes.len() < 8 + 16 + 8 {
        return Err(VocabularyFormatError::Truncated(format!(
            "{} bytes, header needs 32",
            bytes.len()
        )));
    }
    let u32_at =
        |o: usize| u32::from_le_bytes([bytes[o], bytes[o + 1], bytes[o + 2], bytes[o + 3]]);
    let version = u32_at(8);
    if version != FORMAT_VERSION {
        return Err(VocabularyFormatError::Version {
            found: version,
            expected: FORMAT_VERSION,
        });
    }
    let (k, levels, n) = (
        u32_at(12) as usize,
        u32_at(16) as usize,
        u32_at(20) as usize,
    );
    let need = 24usize
        .checked_add(
            n.saturating_sub(1)
                .checked_mul(NODE_BYTES)
                .ok_or_else(|| VocabularyFormatError::Invalid("node count overflows".into()))?,
        )
        .and_then(|x| x.checked_add(8))
        .ok_or_else(|| VocabularyFormatError::Invalid("node count overflows".into()))?;
    if bytes.len() != need {
        return Err(VocabularyFormatError::Truncated(format!(
            "{} bytes for {n} nodes, expected {need}",
            bytes.len()
        )));
    }
    let body = &bytes[..need - 8];
    let mut c = [0u8; 8];
    c.copy_from_slice(&bytes[need - 8..]);
    if fnv1a(body) != u64::from_le_bytes(c) {
        return Err(VocabularyFormatError::Checksum);
    }
    if n == 0 || k < 2 || levels == 0 || levels > 16 {
        return Err(VocabularyFormatError::Invalid(format!(
            "k {k}, levels {levels}, {n} nodes"
        )));
    }
    let mut nodes = Vec::with_capacity(n);
    nodes.push(Node {
        parent: 0,
        children: Vec::new(),
        descriptor: [0; 4],
        weight: 0.0,
        word: None,
    });
    let mut leaves = Vec::with_capacity(n);
    for i in 1..n {
        let o = 24 + (i - 1) * NODE_BYTES;
        let parent = u32_at(o);
        if parent as usize >= i {
            return Err(VocabularyFormatError::Invalid(format!(
                "node {i}: parent {parent} is not an earlier node"
            )));
        }
        let leaf = bytes[o + 4] == 1;
        let mut descriptor = [0u64; 4];
        for (w, d) in descriptor.iter_mut().enumerate() {
            let s = o + 5 + 8 * w;
            let mut a = [0u8; 8];
            a.copy_from_slice(&bytes[s..s + 8]);
            *d = u64::from_le_bytes(a);
        }
        let weight =
            f32::from_le_bytes([bytes[o + 37], bytes[o + 38], bytes[o + 39], bytes[o + 40]]);
        if !weight.is_finite() {
            return Err(VocabularyFormatError::Invalid(format!(
                "node {i}: weight is not finite"
            )));
        }
        nodes.push(Node {
            parent,
            children: Vec::new(),
            descriptor,
            weight,
            word: None,
        });
        nodes[parent as usize].children.push(i as u32);
        if leaf {
            leaves.push(i as u32);
        }
    }
    let mut words = Vec::with_capacity(leaves.len());
    for &l in &leaves {
        if !nodes[l as usize].children.is_empty() {
            return Err(VocabularyFormatError::Invalid(format!(
                "node {l} is marked as a leaf but has children"
            )));
        }
        nodes[l as usize].word = Some(words.len() as u32);
        words.push(l);
    }
    if words.is_empty() {
        return Err(VocabularyFormatError::Invalid("no words".into()));
    }
    Ok(Vocabulary {
        k,
        levels,
        nodes,
        words,
    })
}
