//! Spreading by suppression radius (adaptive non-maximal suppression, Brown et al. 2005, in the
//! greedy grid form of Bailo et al. 2018): corners are taken strongest first, skipping any
//! within `r` of one already taken, with `r` the largest radius that still yields the wanted
//! count. There is no fixed grid whose boundaries move with the image, so the same strong
//! corners win in two views of a scene, and no two features crowd each other.

/// Reusable grid for [`spread_by_radius`].
pub struct SpreadScratch {
    /// Per grid cell: the taken corner in it (at most one, cells being r / sqrt 2 wide).
    cells: Vec<u32>,
    /// Cells written in the current attempt (to clear only those).
    touched: Vec<u32>,
    taken: Vec<u32>,
}

const EMPTY: u32 = u32::MAX;
/// Smallest radius tried (level pixels); the grid is sized for it.
const MIN_RADIUS: f32 = 2.0;

impl SpreadScratch {
    /// Scratch for regions of up to `width` x `height` pixels and `max_corners` corners.
    pub fn new(width: usize, height: usize, max_corners: usize) -> Self {
        let c = MIN_RADIUS / std::f32::consts::SQRT_2;
        let cells = ((width as f32 / c) as usize + 2) * ((height as f32 / c) as usize + 2);
        SpreadScratch {
            cells: vec![EMPTY; cells],
            touched: Vec::with_capacity(max_corners),
            taken: Vec::with_capacity(max_corners),
        }
    }
}

/// Greedy pass at radius `r`: indices (into `order`) of corners taken, stopping at `wanted`.
fn attempt(
    pts: &[(f32, f32)],
    order: &[u32],
    (x0, y0, x1, y1): (f32, f32, f32, f32),
    r: f32,
    wanted: usize,
    s: &mut SpreadScratch,
) {
    for &c in &s.touched {
        s.cells[c as usize] = EMPTY;
    }
    s.touched.clear();
    s.taken.clear();
    let cell = (r / std::f32::consts::SQRT_2).max(MIN_RADIUS / std::f32::consts::SQRT_2);
    let cols = ((x1 - x0) / cell) as usize + 1;
    let rows = ((y1 - y0) / cell) as usize + 1;
    if cols * rows > s.cells.len() {
        return;
    }
    let reach = (r / cell).ceil() as isize;
    let r2 = r * r;
    for (k, &i) in order.iter().enumerate() {
        let (x, y) = pts[i as usize];
        let cx = (((x - x0) / cell) as isize).clamp(0, cols as isize - 1);
        let cy = (((y - y0) / cell) as isize).clamp(0, rows as isize - 1);
        let mut free = true;
        'near: for ny in (cy - reach).max(0)..=(cy + reach).min(rows as isize - 1) {
            for nx in (cx - reach).max(0)..=(cx + reach).min(cols as isize - 1) {
                let o = s.cells[ny as usize * cols + nx as usize];
                if o != EMPTY {
                    let (ox, oy) = pts[order[o as usize] as usize];
                    if (ox - x) * (ox - x) + (oy - y) * (oy - y) < r2 {
                        free = false;
                        break 'near;
                    }
                }
            }
        }
        if free {
            let at = cy as usize * cols + cx as usize;
            s.cells[at] = k as u32;
            s.touched.push(at as u32);
            s.taken.push(k as u32);
            if s.taken.len() == wanted {
                return;
            }
        }
    }
}

/// Chooses up to `wanted` of the corners at `pts`, visited in `order` (strongest first), spread
/// over `region`: writes the chosen entries of `order` to `out` (cleared first), strongest first.
pub fn spread_by_radius(
    pts: &[(f32, f32)],
    order: &[u32],
    region: (f32, f32, f32, f32),
    wanted: usize,
    s: &mut SpreadScratch,
    out: &mut Vec<u32>,
) {
    out.clear();
    if order.len() <= wanted {
        out.extend_from_slice(order);
        return;
    }
    let (w, h) = (region.2 - region.0, region.3 - region.1);
    // Radius at which `wanted` discs would tile the region; search below and above it.
    let mut hi = (w * h / wanted as f32).sqrt() * 1.5;
    let mut lo = 0.0f32;
    let mut best = 0.0f32;
    for _ in 0..12 {
        let r = 0.5 * (lo + hi);
        attempt(pts, order, region, r, wanted, s);
        if s.taken.len() >= wanted {
            best = r;
            lo = r;
        } else {
            hi = r;
        }
        if hi - lo < 0.25 {
            break;
        }
    }
    if best > 0.0 {
        attempt(pts, order, region, best, wanted, s);
        out.extend(s.taken.iter().map(|&k| order[k as usize]));
    } else {
        out.extend_from_slice(&order[..wanted]);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn keeps_the_count_spreads_a_cluster_and_keeps_the_strongest() {
        // 2000 points, 90% in a 100x100 corner of a 600x440 region; order = strongest first.
        let pts: Vec<(f32, f32)> = super::super::distribute::clustered_points(2000, 7)
            .into_iter()
            .map(|(x, y, _)| (x as f32, y as f32))
            .collect();
        let order: Vec<u32> = (0..2000).collect();
        let mut scratch = SpreadScratch::new(600, 440, 2000);
        let mut out = Vec::new();
        spread_by_radius(
            &pts,
            &order,
            (0.0, 0.0, 600.0, 440.0),
            150,
            &mut scratch,
            &mut out,
        );
        assert_eq!(out.len(), 150);
        assert_eq!(out[0], 0, "the strongest is always kept");
        let in_cluster = out
            .iter()
            .filter(|&&i| pts[i as usize].0 < 100.0 && pts[i as usize].1 < 100.0)
            .count();
        assert!(in_cluster < out.len() / 3, "{in_cluster} of {}", out.len());
        // No two chosen points closer than the radius used by most pairs: at least 10 px here.
        let min_d = out
            .iter()
            .flat_map(|&a| out.iter().map(move |&b| (a, b)))
            .filter(|(a, b)| a < b)
            .map(|(a, b)| {
                let (p, q) = (pts[a as usize], pts[b as usize]);
                ((p.0 - q.0).powi(2) + (p.1 - q.1).powi(2)).sqrt()
            })
            .fold(f32::MAX, f32::min);
        assert!(min_d >= 10.0, "{min_d}");
    }
}
