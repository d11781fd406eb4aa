//! Vocabulary training: hierarchical k-means++ on binary descriptors with Hamming distance and
//! majority-bit centroids, then idf weights `ln(N / n_i)` from the training images.

use super::vocabulary::{Node, Vocabulary};
use crate::features::Descriptor;
use crate::geometry::ransac::SeededRng;
use crate::matching::hamming;

#[derive(Clone, Debug)]
pub struct TrainConfig {
    /// Branching factor (DBoW2: 10).
    pub k: usize,
    /// Depth (10^L words at most).
    pub levels: usize,
    pub iterations: usize,
    pub seed: u64,
}

impl Default for TrainConfig {
    fn default() -> Self {
        TrainConfig {
            k: 10,
            levels: 5,
            iterations: 10,
            seed: 0,
        }
    }
}

/// Majority bit per position.
fn centroid(members: &[&Descriptor]) -> Descriptor {
    let mut counts = [0u32; 256];
    for d in members {
        for (b, c) in counts.iter_mut().enumerate() {
            *c += ((d[b >> 6] >> (b & 63)) & 1) as u32;
        }
    }
    let half = members.len() as u32;
    let mut out = [0u64; 4];
    for (b, &c) in counts.iter().enumerate() {
        if 2 * c > half {
            out[b >> 6] |= 1u64 << (b & 63);
        }
    }
    out
}

/// k-means++ clustering of `ds` into at most `k` groups (indices into `ds`).
fn kmeans(ds: &[&Descriptor], k: usize, iterations: usize, rng: &mut SeededRng) -> Vec<Vec<usize>> {
    if ds.len() <= k {
        return (0..ds.len()).map(|i| vec![i]).collect();
    }
    // k-means++ seeding: next centre with probability proportional to squared distance.
    let mut centres: Vec<Descriptor> = vec![*ds[rng.below(ds.len())]];
    let mut d2: Vec<f64> = ds
        .iter()
        .map(|d| (hamming(d, &centres[0]) as f64).powi(2))
        .collect();
    while centres.len() < k {
        let total: f64 = d2.iter().sum();
        if total <= 0.0 {
            break;
        }
        let mut r = (rng.next_u64() >> 11) as f64 / (1u64 << 53) as f64 * total;
        let mut pick = ds.len() - 1;
        for (i, v) in d2.iter().enumerate() {
            r -= v;
            if r <= 0.0 {
                pick = i;
                break;
            }
        }
        centres.push(*ds[pick]);
        for (i, d) in ds.iter().enumerate() {
            d2[i] = d2[i].min((hamming(d, ds[pick]) as f64).powi(2));
        }
    }
    let mut assign = vec![usize::MAX; ds.len()];
    for _ in 0..iterations.max(1) {
        let mut changed = false;
        for (i, d) in ds.iter().enumerate() {
            let best = (0..centres.len())
                .min_by_key(|&c| hamming(d, &centres[c]))
                .unwrap_or(0);
            changed |= assign[i] != best;
            assign[i] = best;
        }
        for (c, centre) in centres.iter_mut().enumerate() {
            let members: Vec<&Descriptor> = ds
                .iter()
                .zip(&assign)
                .filter(|(_, &a)| a == c)
                .map(|(d, _)| *d)
                .collect();
            if !members.is_empty() {
                *centre = centroid(&members);
            }
        }
        if !changed {
            break;
        }
    }
    let mut groups = vec![Vec::new(); centres.len()];
    for (i, &a) in assign.iter().enumerate() {
        groups[a].push(i);
    }
    groups.retain(|g| !g.is_empty());
    groups
}

/// Trains on `images` (the descriptors of each training image).
pub fn train(images: &[Vec<Descriptor>], cfg: &TrainConfig) -> Option<Vocabulary> {
    let all: Vec<&Descriptor> = images.iter().flatten().collect();
    if all.is_empty() || cfg.k < 2 || cfg.levels == 0 {
        return None;
    }
    let mut rng = SeededRng::new(cfg.seed);
    let mut nodes = vec![Node {
        parent: 0,
        children: Vec::new(),
        descriptor: [0; 4],
        weight: 0.0,
        word: None,
    }];
    // Breadth-first: (node, member descriptors, depth).
    let mut queue = std::collections::VecDeque::new();
    queue.push_back((0u32, (0..all.len()).collect::<Vec<usize>>(), 0usize));
    while let Some((node, members, depth)) = queue.pop_front() {
        if depth == cfg.levels || members.len() <= 1 {
            continue;
        }
        let ds: Vec<&Descriptor> = members.iter().map(|&i| all[i]).collect();
        let groups = kmeans(&ds, cfg.k, cfg.iterations, &mut rng);
        if groups.len() <= 1 && depth > 0 {
            continue;
        }
        for g in groups {
            let gm: Vec<usize> = g.iter().map(|&i| members[i]).collect();
            let refs: Vec<&Descriptor> = gm.iter().map(|&i| all[i]).collect();
            let id = nodes.len() as u32;
            nodes.push(Node {
                parent: node,
                children: Vec::new(),
                descriptor: centroid(&refs),
                weight: 0.0,
                word: None,
            });
            nodes[node as usize].children.push(id);
            queue.push_back((id, gm, depth + 1));
        }
    }
    let mut words = Vec::new();
    for (i, node) in nodes.iter_mut().enumerate().skip(1) {
        if node.children.is_empty() {
            node.word = Some(words.len() as u32);
            words.push(i as u32);
        }
    }
    let mut v = Vocabulary {
        k: cfg.k,
        levels: cfg.levels,
        nodes,
        words,
    };
    // idf: ln(N / images containing the word).
    let n = images.len() as f32;
    let mut seen = vec![0u32; v.words.len()];
    for img in images {
        let mut ws: Vec<u32> = img
            .iter()
            .filter_map(|d| v.lookup(d, 0).map(|(w, _, _)| w))
            .collect();
        ws.sort_unstable();
        ws.dedup();
        for w in ws {
            seen[w as usize] += 1;
        }
    }
    for (w, &node) in v.words.iter().enumerate() {
        v.nodes[node as usize].weight = if seen[w] > 0 {
            (n / seen[w] as f32).ln()
        } else {
            0.0
        };
    }
    Some(v)
}
