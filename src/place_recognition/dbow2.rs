//! Import of DBoW2 text vocabularies (ORB-SLAM's `ORBvoc.txt` layout): a header `k L scoring
//! weighting`, then one line per node after the root, in breadth-first order:
//! `parent isLeaf d0 .. d31 weight` (descriptor bytes as decimal).

use super::vocabulary::{Node, Vocabulary};
use super::VocabularyFormatError;

/// Parses the text; errors name the 1-based line.
pub fn parse_dbow2_text(text: &str) -> Result<Vocabulary, VocabularyFormatError> {
    let bad = |line: usize, m: String| VocabularyFormatError::Text { line, message: m };
    let mut lines = text.lines().enumerate();
    let (hl, header) = lines.next().ok_or_else(|| bad(1, "empty file".into()))?;
    let h: Vec<usize> = header
        .split_whitespace()
        .map(|t| {
            t.parse::<usize>()
                .map_err(|_| bad(hl + 1, format!("header field {t:?} is not an integer")))
        })
        .collect::<Result<_, _>>()?;
    if h.len() != 4 || h[0] < 2 || h[1] < 1 || h[1] > 16 {
        return Err(bad(
            hl + 1,
            "expected `k L scoring weighting` with k >= 2 and 1 <= L <= 16".into(),
        ));
    }
    let (k, levels) = (h[0], h[1]);
    let mut nodes = vec![Node {
        parent: 0,
        children: Vec::new(),
        descriptor: [0; 4],
        weight: 0.0,
        word: None,
    }];
    let mut words = Vec::new();
    for (i, raw) in lines {
        let line = i + 1;
        let t = raw.trim();
        if t.is_empty() {
            continue;
        }
        let toks: Vec<&str> = t.split_whitespace().collect();
        if toks.len() != 35 {
            return Err(bad(
                line,
                format!(
                    "expected 35 fields (parent isLeaf 32 bytes weight), found {}",
                    toks.len()
                ),
            ));
        }
        let parent: u32 = toks[0]
            .parse()
            .map_err(|_| bad(line, format!("parent {:?} is not an integer", toks[0])))?;
        if parent as usize >= nodes.len() {
            return Err(bad(line, format!("parent {parent} is not an earlier node")));
        }
        let leaf = match toks[1] {
            "0" => false,
            "1" => true,
            o => return Err(bad(line, format!("isLeaf {o:?} is not 0 or 1"))),
        };
        let mut bytes = [0u8; 32];
        for (b, tok) in bytes.iter_mut().zip(&toks[2..34]) {
            *b = tok
                .parse()
                .map_err(|_| bad(line, format!("descriptor byte {tok:?} is not 0..=255")))?;
        }
        let weight: f32 = toks[34]
            .parse()
            .ok()
            .filter(|w: &f32| w.is_finite())
            .ok_or_else(|| {
                bad(
                    line,
                    format!("weight {:?} is not a finite number", toks[34]),
                )
            })?;
        let mut descriptor = [0u64; 4];
        for (w, chunk) in descriptor.iter_mut().zip(bytes.chunks_exact(8)) {
            let mut a = [0u8; 8];
            a.copy_from_slice(chunk);
            *w = u64::from_le_bytes(a);
        }
        let id = nodes.len() as u32;
        let word = leaf.then(|| {
            words.push(id);
            (words.len() - 1) as u32
        });
        nodes.push(Node {
            parent,
            children: Vec::new(),
            descriptor,
            weight,
            word,
        });
        nodes[parent as usize].children.push(id);
    }
    if words.is_empty() {
        return Err(bad(1, "the vocabulary has no words".into()));
    }
    Ok(Vocabulary {
        k,
        levels,
        nodes,
        words,
    })
}
