//! Quadtree distribution of corners (ORB-SLAM's scheme): split the level into nodes until there
//! are as many nodes as wanted features, then keep the strongest corner of each node. Spreads
//! features over the image instead of clustering them on the most textured object.
//!
//! Nodes hold ranges of one index array that splitting partitions in place, so the scratch
//! vectors are reused from frame to frame without allocating.

use std::collections::BinaryHeap;

use super::fast::Corner;

#[derive(Clone, Copy, Debug)]
struct Node {
    x0: f32,
    y0: f32,
    x1: f32,
    y1: f32,
    start: u32,
    end: u32,
}

impl Node {
    fn len(&self) -> usize {
        (self.end - self.start) as usize
    }
}

/// Reusable scratch for [`distribute`].
#[derive(Default)]
pub struct QuadtreeScratch {
    /// The corners being partitioned, by value (no dependent loads while splitting).
    idx: Vec<Slot>,
    nodes: Vec<Node>,
    next: Vec<Node>,
    heap: BinaryHeap<ByLen>,
}

/// A node ordered by its corner count (then position, so the order is deterministic).
struct ByLen(Node);

impl ByLen {
    fn key(&self) -> (u32, u32) {
        (self.0.end - self.0.start, u32::MAX - self.0.start)
    }
}

impl PartialEq for ByLen {
    fn eq(&self, o: &Self) -> bool {
        self.key() == o.key()
    }
}
impl Eq for ByLen {}
impl PartialOrd for ByLen {
    fn partial_cmp(&self, o: &Self) -> Option<std::cmp::Ordering> {
        Some(self.cmp(o))
    }
}
impl Ord for ByLen {
    fn cmp(&self, o: &Self) -> std::cmp::Ordering {
        self.key().cmp(&o.key())
    }
}

impl QuadtreeScratch {
    pub fn with_capacity(corners: usize, nodes: usize) -> Self {
        QuadtreeScratch {
            idx: Vec::with_capacity(corners),
            nodes: Vec::with_capacity(nodes * 4 + 16),
            next: Vec::with_capacity(nodes * 4 + 16),
            heap: BinaryHeap::with_capacity(nodes * 4 + 16),
        }
    }
}

/// A corner's position, and its score (high byte) over its index (low 24 bits), so the
/// largest key is the strongest corner.
#[derive(Clone, Copy, Debug)]
struct Slot {
    x: u16,
    y: u16,
    key: u32,
}

impl Slot {
    fn index(&self) -> u32 {
        self.key & 0x00ff_ffff
    }
}

/// Partitions `idx[s..e]` so corners with `pred` true come first; returns the split point.
/// Branch-free (the predicate is a coin toss on textured images): every element is swapped
/// to the boundary and the boundary advances when it belongs to the first part.
#[inline(always)]
fn partition(idx: &mut [Slot], s: usize, e: usize, pred: impl Fn(&Slot) -> bool) -> usize {
    let mut i = s;
    for j in s..e {
        let v = idx[j];
        idx.swap(i, j);
        i += pred(&v) as usize;
    }
    i
}

/// Splits `n` into up to 4 non-empty children pushed to `out`.
fn split(n: &Node, idx: &mut [Slot], out: &mut Vec<Node>) {
    let mx = 0.5 * (n.x0 + n.x1);
    let my = 0.5 * (n.y0 + n.y1);
    let (s, e) = (n.start as usize, n.end as usize);
    let ym = partition(idx, s, e, |c| (c.y as f32) < my);
    let xa = partition(idx, s, ym, |c| (c.x as f32) < mx);
    let xb = partition(idx, ym, e, |c| (c.x as f32) < mx);
    let kids = [
        (n.x0, n.y0, mx, my, s, xa),
        (mx, n.y0, n.x1, my, xa, ym),
        (n.x0, my, mx, n.y1, ym, xb),
        (mx, my, n.x1, n.y1, xb, e),
    ];
    for (x0, y0, x1, y1, a, b) in kids {
        if b > a {
            out.push(Node {
                x0,
                y0,
                x1,
                y1,
                start: a as u32,
                end: b as u32,
            });
        }
    }
}

/// Selects about `wanted` corners spread over `[x0, x1) x [y0, y1)`: indices into `corners`,
/// written to `selected` (cleared first).
pub fn distribute(
    corners: &[Corner],
    (x0, y0, x1, y1): (f32, f32, f32, f32),
    wanted: usize,
    scratch: &mut QuadtreeScratch,
    selected: &mut Vec<u32>,
) {
    selected.clear();
    if corners.is_empty() || wanted == 0 {
        return;
    }
    let QuadtreeScratch {
        idx,
        nodes,
        next,
        heap,
    } = scratch;
    idx.clear();
    // Indices fit 24 bits: at most one corner per pixel of a level (checked).
    assert!(corners.len() < 1 << 24, "too many corners for the quadtree");
    idx.extend(corners.iter().enumerate().map(|(i, c)| Slot {
        x: c.x,
        y: c.y,
        key: (c.score as u32) << 24 | i as u32,
    }));
    nodes.clear();
    // Initial nodes: roughly square, as many columns as the aspect ratio.
    let (w, h) = (x1 - x0, y1 - y0);
    let n_ini = ((w / h).round() as usize).max(1);
    let hx = w / n_ini as f32;
    let mut start = 0usize;
    for i in 0..n_ini {
        let (a, b) = (x0 + hx * i as f32, x0 + hx * (i + 1) as f32);
        let last = i + 1 == n_ini;
        let end = partition(idx, start, corners.len(), |c| last || (c.x as f32) < b);
        if end > start {
            nodes.push(Node {
                x0: a,
                y0,
                x1: b,
                y1,
                start: start as u32,
                end: end as u32,
            });
        }
        start = end;
    }
    loop {
        let before = nodes.len();
        next.clear();
        let mut splittable = 0;
        for n in nodes.iter() {
            if n.len() == 1 || (n.x1 - n.x0) < 1.0 {
                next.push(*n);
            } else {
                let m = next.len();
                split(n, idx, next);
                splittable += (next.len() - m > 1) as usize;
            }
        }
        std::mem::swap(nodes, next);
        if nodes.len() >= wanted || nodes.len() == before || splittable == 0 {
            break;
        }
        // Close to the target: split the most populated nodes one by one (a max-heap on the
        // corner count; children go back on the heap).
        if nodes.len() + splittable * 3 > wanted {
            heap.clear();
            heap.extend(nodes.drain(..).map(ByLen));
            while heap.len() + nodes.len() < wanted {
                let Some(top) = heap.peek() else { break };
                if top.0.len() <= 1 {
                    break;
                }
                let Some(ByLen(n)) = heap.pop() else { break };
                if n.x1 - n.x0 < 1.0 {
                    // Too small to split: set aside (never split again).
                    nodes.push(n);
                    continue;
                }
                next.clear();
                split(&n, idx, next);
                heap.extend(next.drain(..).map(ByLen));
            }
            nodes.extend(heap.drain().map(|b| b.0));
            break;
        }
    }
    for n in nodes.iter() {
        let best = idx[n.start as usize..n.end as usize]
            .iter()
            .map(|c| c.key)
            .max()
            .unwrap_or(idx[n.start as usize].key);
        selected.push(
            Slot {
                x: 0,
                y: 0,
                key: best,
            }
            .index(),
        );
    }
    // Overshoot of the last split round: keep the strongest `wanted`.
    if selected.len() > wanted {
        selected.sort_unstable_by_key(|&i| std::cmp::Reverse(corners[i as usize].score));
        selected.truncate(wanted);
    }
}

/// Test data: `n` points (x, y, random word), 90% in a 100x100 corner of a 600x440 area.
#[cfg(test)]
pub(super) fn clustered_points(n: usize, seed: u64) -> Vec<(u32, u32, u32)> {
    let mut s = seed;
    (0..n)
        .map(|i| {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            let r = (s >> 33) as u32;
            if i % 10 == 0 {
                (r % 600, (r / 600) % 440, r)
            } else {
                (r % 100, (r / 100) % 100, r)
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn spreads_clustered_corners_and_respects_count() {
        // 2000 corners, 90% clustered in one corner of the image.
        let corners: Vec<Corner> = clustered_points(2000, 1)
            .into_iter()
            .map(|(x, y, r)| Corner {
                x: x as u16 + 20,
                y: y as u16 + 20,
                score: (r % 200) as u8 + 10,
            })
            .collect();
        let mut scratch = QuadtreeScratch::with_capacity(2000, 300);
        let mut sel = Vec::new();
        distribute(
            &corners,
            (20.0, 20.0, 620.0, 460.0),
            300,
            &mut scratch,
            &mut sel,
        );
        assert!(sel.len() <= 300 && sel.len() >= 250, "{}", sel.len());
        let in_cluster = sel
            .iter()
            .filter(|&&i| corners[i as usize].x < 120 && corners[i as usize].y < 120)
            .count();
        // The cluster covers ~4% of the area: most selected corners must lie outside it.
        assert!(in_cluster < sel.len() / 2, "{in_cluster} of {}", sel.len());
        let mut u = sel.clone();
        u.sort();
        u.dedup();
        assert_eq!(u.len(), sel.len());
    }

    #[test]
    fn fewer_corners_than_wanted_keeps_all() {
        let corners: Vec<Corner> = (0..10)
            .map(|i| Corner {
                x: 30 + i * 40,
                y: 50,
                score: 30,
            })
            .collect();
        let mut sel = Vec::new();
        distribute(
            &corners,
            (0.0, 0.0, 640.0, 480.0),
            100,
            &mut QuadtreeScratch::default(),
            &mut sel,
        );
        assert_eq!(sel.len(), 10);
    }
}
