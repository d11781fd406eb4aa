//! Chessboard detection: saddle points of the smoothed image (X-junctions of the board), kept
//! when the ring around them alternates dark/bright four times, refined to sub-pixel by
//! gradient orthogonality, then linked into the board's grid by growing a lattice from a seed
//! with linear prediction (tolerates perspective and lens distortion).

use std::collections::BTreeMap;

use nalgebra::{Matrix2, Vector2};

/// Inner-corner count of a board: `cols` along its long side, `rows` along the other.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct BoardSize {
    pub cols: usize,
    pub rows: usize,
}

/// Parameters of the detector.
#[derive(Clone, Debug)]
pub struct DetectorConfig {
    /// Gaussian smoothing before the saddle response (pixels).
    pub sigma: f32,
    /// Saddle response threshold, relative to the strongest response in the image.
    pub relative_threshold: f32,
    /// Most candidates kept (strongest first).
    pub max_candidates: usize,
    /// Half-size of the sub-pixel refinement window (pixels); shrunk for small squares.
    pub subpix_radius: i32,
}

impl Default for DetectorConfig {
    fn default() -> Self {
        DetectorConfig {
            sigma: 1.5,
            relative_threshold: 0.05,
            max_candidates: 600,
            subpix_radius: 5,
        }
    }
}

/// Detected inner corners in board order: index `j * cols + i` is corner (i, j), which sits at
/// board coordinates (i * square, j * square, 0). The order is right-handed (board z towards
/// the camera's back) so every view's pose is a proper rotation.
pub fn detect(
    gray: &[u8],
    width: usize,
    height: usize,
    board: BoardSize,
    cfg: &DetectorConfig,
) -> Option<Vec<Vector2<f64>>> {
    if width < 16 || height < 16 || gray.len() < width * height || board.cols < 2 || board.rows < 2
    {
        return None;
    }
    let img: Vec<f32> = gray[..width * height].iter().map(|&v| v as f32).collect();
    let smooth = gaussian_blur(&img, width, height, cfg.sigma);
    let mut cands = saddle_candidates(&smooth, width, height, cfg);
    let light = gaussian_blur(&img, width, height, 0.7);
    cands.retain(|p| is_x_junction(&smooth, width, height, *p, 4.0 * cfg.sigma as f64));
    if cands.len() < board.cols * board.rows {
        return None;
    }
    let spacing = median_neighbour_distance(&cands);
    let radius = cfg.subpix_radius.min(((spacing * 0.4) as i32).max(2));
    for p in cands.iter_mut() {
        *p = refine_subpixel(&light, width, height, *p, radius);
    }
    let grid = grow_grid(&cands, board)?;
    Some(orient(&grid, board, &smooth, width, height))
}

/// Separable Gaussian blur (clamped borders).
pub fn gaussian_blur(img: &[f32], w: usize, h: usize, sigma: f32) -> Vec<f32> {
    let r = (3.0 * sigma).ceil() as i32;
    let k: Vec<f32> = (-r..=r)
        .map(|i| (-(i * i) as f32 / (2.0 * sigma * sigma)).exp())
        .collect();
    let sum: f32 = k.iter().sum();
    let k: Vec<f32> = k.iter().map(|v| v / sum).collect();
    let mut tmp = vec![0.0f32; w * h];
    for y in 0..h {
        for x in 0..w {
            let mut acc = 0.0;
            for (i, kv) in k.iter().enumerate() {
                let xx = (x as i32 + i as i32 - r).clamp(0, w as i32 - 1) as usize;
                acc += kv * img[y * w + xx];
            }
            tmp[y * w + x] = acc;
        }
    }
    let mut out = vec![0.0f32; w * h];
    for y in 0..h {
        for x in 0..w {
            let mut acc = 0.0;
            for (i, kv) in k.iter().enumerate() {
                let yy = (y as i32 + i as i32 - r).clamp(0, h as i32 - 1) as usize;
                acc += kv * tmp[yy * w + x];
            }
            out[y * w + x] = acc;
        }
    }
    out
}

/// Local maxima of the saddle response `Ixy^2 - Ixx * Iyy` (positive only at saddles).
fn saddle_candidates(s: &[f32], w: usize, h: usize, cfg: &DetectorConfig) -> Vec<Vector2<f64>> {
    let mut resp = vec![0.0f32; w * h];
    let mut max = 0.0f32;
    for y in 2..h - 2 {
        for x in 2..w - 2 {
            let i = y * w + x;
            let ixx = s[i + 1] - 2.0 * s[i] + s[i - 1];
            let iyy = s[i + w] - 2.0 * s[i] + s[i - w];
            let ixy = (s[i + w + 1] - s[i + w - 1] - s[i - w + 1] + s[i - w - 1]) * 0.25;
            let r = ixy * ixy - ixx * iyy;
            if r > 0.0 {
                resp[i] = r;
                max = max.max(r);
            }
        }
    }
    if max <= 0.0 {
        return Vec::new();
    }
    let thr = max * cfg.relative_threshold;
    let nms = 3i32;
    let mut found: Vec<(f32, Vector2<f64>)> = Vec::new();
    let border = 4;
    for y in border..h - border {
        'px: for x in border..w - border {
            let v = resp[y * w + x];
            if v < thr {
                continue;
            }
            for dy in -nms..=nms {
                for dx in -nms..=nms {
                    let (xx, yy) = (x as i32 + dx, y as i32 + dy);
                    if xx < 0 || yy < 0 || xx >= w as i32 || yy >= h as i32 || (dx == 0 && dy == 0)
                    {
                        continue;
                    }
                    let o = resp[yy as usize * w + xx as usize];
                    // Strict on one side so plateaus keep exactly one pixel.
                    if o > v || (o == v && (dy < 0 || (dy == 0 && dx < 0))) {
                        continue 'px;
                    }
                }
            }
            found.push((v, Vector2::new(x as f64, y as f64)));
        }
    }
    found.sort_by(|a, b| b.0.total_cmp(&a.0));
    found.truncate(cfg.max_candidates);
    found.into_iter().map(|(_, p)| p).collect()
}

/// Bilinear sample (clamped).
fn sample(img: &[f32], w: usize, h: usize, x: f64, y: f64) -> f32 {
    let x = x.clamp(0.0, (w - 1) as f64 - 1e-6);
    let y = y.clamp(0.0, (h - 1) as f64 - 1e-6);
    let (x0, y0) = (x.floor() as usize, y.floor() as usize);
    let (ax, ay) = ((x - x0 as f64) as f32, (y - y0 as f64) as f32);
    let i = y0 * w + x0;
    let (a, b) = (img[i], img[(i + 1).min(img.len() - 1)]);
    let (c, d) = (
        img[(i + w).min(img.len() - 1)],
        img[(i + w + 1).min(img.len() - 1)],
    );
    (a * (1.0 - ax) + b * ax) * (1.0 - ay) + (c * (1.0 - ax) + d * ax) * ay
}

/// An X-junction: on a ring around it the intensity crosses its mean exactly four times, with
/// contrast (rejects edges, blobs and texture).
fn is_x_junction(img: &[f32], w: usize, h: usize, p: Vector2<f64>, radius: f64) -> bool {
    const N: usize = 32;
    let mut ring = [0.0f32; N];
    for (k, v) in ring.iter_mut().enumerate() {
        let a = k as f64 * std::f64::consts::TAU / N as f64;
        *v = sample(img, w, h, p.x + radius * a.cos(), p.y + radius * a.sin());
    }
    let (lo, hi) = ring
        .iter()
        .fold((f32::MAX, f32::MIN), |(l, u), &v| (l.min(v), u.max(v)));
    if hi - lo < 20.0 {
        return false;
    }
    let mid = 0.5 * (lo + hi);
    let band = 0.15 * (hi - lo);
    // Hysteresis: a side changes only when clearly past the middle.
    let mut state: Option<bool> = None;
    let mut first: Option<bool> = None;
    let mut changes = 0;
    for v in ring.iter().chain(ring.iter()) {
        let s = if *v > mid + band {
            Some(true)
        } else if *v < mid - band {
            Some(false)
        } else {
            None
        };
        if let Some(s) = s {
            match state {
                None => {
                    state = Some(s);
                    first = Some(s);
                }
                Some(prev) if prev != s => {
                    changes += 1;
                    state = Some(s);
                }
                _ => {}
            }
        }
    }
    let _ = first;
    // Two passes round the ring: an X-junction changes side 4 times per turn.
    (7..=9).contains(&changes)
}

/// Gradient-orthogonality refinement: the corner q satisfies sum g g^T (q - x) = 0 over a window
/// (every gradient in the window is orthogonal to the vector from the corner).
pub fn refine_subpixel(
    img: &[f32],
    w: usize,
    h: usize,
    start: Vector2<f64>,
    radius: i32,
) -> Vector2<f64> {
    let mut q = start;
    let sigma = radius as f64 * 0.6;
    for _ in 0..20 {
        let mut a = Matrix2::zeros();
        let mut b = Vector2::zeros();
        for dy in -radius..=radius {
            for dx in -radius..=radius {
                let (x, y) = (q.x + dx as f64, q.y + dy as f64);
                if x < 1.0 || y < 1.0 || x >= (w - 2) as f64 || y >= (h - 2) as f64 {
                    continue;
                }
                let gx =
                    (sample(img, w, h, x + 1.0, y) - sample(img, w, h, x - 1.0, y)) as f64 * 0.5;
                let gy =
                    (sample(img, w, h, x, y + 1.0) - sample(img, w, h, x, y - 1.0)) as f64 * 0.5;
                let wgt = (-((dx * dx + dy * dy) as f64) / (2.0 * sigma * sigma)).exp();
                let g = Vector2::new(gx, gy);
                let ggt = g * g.transpose() * wgt;
                a += ggt;
                b += ggt * Vector2::new(x, y);
            }
        }
        let Some(inv) = a.try_inverse() else { break };
        let next = inv * b;
        if !next.x.is_finite() || (next - start).norm() > radius as f64 {
            return start;
        }
        let step = (next - q).norm();
        q = next;
        if step < 1e-3 {
            break;
        }
    }
    q
}

fn median_neighbour_distance(pts: &[Vector2<f64>]) -> f64 {
    let mut d: Vec<f64> = pts
        .iter()
        .enumerate()
        .map(|(i, p)| {
            pts.iter()
                .enumerate()
                .filter(|(j, _)| *j != i)
                .map(|(_, q)| (q - p).norm())
                .fold(f64::MAX, f64::min)
        })
        .collect();
    d.sort_by(|a, b| a.total_cmp(b));
    d.get(d.len() / 2).copied().unwrap_or(10.0)
}

/// Lattice index -> candidate index (ordered: the growth, which starts from its keys, must not
/// depend on a hash seed, or a view can be found in one run and missed in the next).
type Lattice = BTreeMap<(i32, i32), usize>;

/// Tries seeds near the candidates' centre until one grows into a full `cols x rows` lattice.
/// Returns corner positions indexed `[j][i]` in lattice order (orientation fixed later).
fn grow_grid(cands: &[Vector2<f64>], board: BoardSize) -> Option<Vec<Vec<Vector2<f64>>>> {
    let n = cands.len();
    let centre = cands.iter().fold(Vector2::zeros(), |a, p| a + p) / n as f64;
    let mut order: Vec<usize> = (0..n).collect();
    order.sort_by(|&a, &b| {
        (cands[a] - centre)
            .norm()
            .total_cmp(&(cands[b] - centre).norm())
    });
    for &seed in order.iter().take(25) {
        if let Some(g) = grow_from(cands, seed, board) {
            return Some(g);
        }
    }
    None
}

fn nearest(cands: &[Vector2<f64>], p: Vector2<f64>, exclude: usize) -> Option<(usize, f64)> {
    cands
        .iter()
        .enumerate()
        .filter(|(i, _)| *i != exclude)
        .map(|(i, q)| (i, (q - p).norm()))
        .min_by(|a, b| a.1.total_cmp(&b.1))
}

fn grow_from(
    cands: &[Vector2<f64>],
    seed: usize,
    board: BoardSize,
) -> Option<Vec<Vec<Vector2<f64>>>> {
    let p0 = cands[seed];
    let (n1, d1) = nearest(cands, p0, seed)?;
    let e1 = cands[n1] - p0;
    // Second axis: the nearest neighbour clearly off the first axis.
    let n2 = cands
        .iter()
        .enumerate()
        .filter(|(i, q)| {
            let d = *q - p0;
            *i != seed
                && *i != n1
                && d.norm() < 2.0 * d1
                && (d.normalize().dot(&e1.normalize())).abs() < 0.5
        })
        .min_by(|a, b| (a.1 - p0).norm().total_cmp(&(b.1 - p0).norm()))?
        .0;
    let mut lat: Lattice = BTreeMap::new();
    let mut used = vec![false; cands.len()];
    for (k, idx) in [((0, 0), seed), ((1, 0), n1), ((0, 1), n2)] {
        lat.insert(k, idx);
        used[idx] = true;
    }
    let max_extent = (board.cols.max(board.rows)) as i32;
    let mut frontier: Vec<(i32, i32)> = lat.keys().copied().collect();
    while let Some((i, j)) = frontier.pop() {
        for (di, dj) in [(1, 0), (-1, 0), (0, 1), (0, -1)] {
            let key = (i + di, j + dj);
            if lat.contains_key(&key) {
                continue;
            }
            let Some(pred) = predict(cands, &lat, key, (di, dj)) else {
                continue;
            };
            let step = (pred - cands[lat[&(i, j)]]).norm();
            let Some((c, dist)) = cands
                .iter()
                .enumerate()
                .filter(|(k, _)| !used[*k])
                .map(|(k, q)| (k, (q - pred).norm()))
                .min_by(|a, b| a.1.total_cmp(&b.1))
            else {
                continue;
            };
            if dist < 0.3 * step {
                lat.insert(key, c);
                used[c] = true;
                frontier.push(key);
                let (imin, imax, jmin, jmax) = extent(&lat);
                if imax - imin + 1 > max_extent || jmax - jmin + 1 > max_extent {
                    return None;
                }
            }
        }
    }
    let (imin, imax, jmin, jmax) = extent(&lat);
    let (ni, nj) = ((imax - imin + 1) as usize, (jmax - jmin + 1) as usize);
    let fits = (ni, nj) == (board.cols, board.rows) || (ni, nj) == (board.rows, board.cols);
    if !fits || lat.len() != ni * nj {
        return None;
    }
    let mut grid = vec![vec![Vector2::zeros(); ni]; nj];
    for ((i, j), idx) in &lat {
        grid[(j - jmin) as usize][(i - imin) as usize] = cands[*idx];
    }
    Some(grid)
}

fn extent(lat: &Lattice) -> (i32, i32, i32, i32) {
    lat.keys().fold(
        (i32::MAX, i32::MIN, i32::MAX, i32::MIN),
        |(a, b, c, d), &(i, j)| (a.min(i), b.max(i), c.min(j), d.max(j)),
    )
}

/// Where lattice cell `key` should be, stepping `dir` from its neighbour: linear extrapolation
/// along the row/column when two cells back exist (follows perspective and distortion), else
/// the neighbour plus the local step of the other rows/columns.
fn predict(
    cands: &[Vector2<f64>],
    lat: &Lattice,
    key: (i32, i32),
    dir: (i32, i32),
) -> Option<Vector2<f64>> {
    let at = |k: (i32, i32)| lat.get(&k).map(|&i| cands[i]);
    let prev = at((key.0 - dir.0, key.1 - dir.1))?;
    if let Some(prev2) = at((key.0 - 2 * dir.0, key.1 - 2 * dir.1)) {
        return Some(prev + (prev - prev2));
    }
    // One step back only: borrow the step from a parallel line.
    let (pi, pj) = (dir.1, dir.0); // perpendicular
    for s in [1, -1] {
        let side = (key.0 + s * pi, key.1 + s * pj);
        let side_prev = (side.0 - dir.0, side.1 - dir.1);
        if let (Some(a), Some(b)) = (at(side), at(side_prev)) {
            return Some(prev + (a - b));
        }
    }
    None
}

/// Puts the grid in board order: `cols` along i, right-handed, and (where the board's colours
/// tell) the dark square at the first cell.
fn orient(
    grid: &[Vec<Vector2<f64>>],
    board: BoardSize,
    img: &[f32],
    w: usize,
    h: usize,
) -> Vec<Vector2<f64>> {
    let (nj, ni) = (grid.len(), grid[0].len());
    // Square boards need no transpose (it is a rotation once handedness is fixed).
    let keep = ni == board.cols || board.cols == board.rows;
    let mut cells: Vec<Vec<Vector2<f64>>> = if keep {
        grid.to_vec()
    } else {
        (0..ni)
            .map(|i| (0..nj).map(|j| grid[j][i]).collect())
            .collect()
    };
    let (rows, cols) = (cells.len(), cells[0].len());
    // Handedness: image x along i, y along j => cross > 0 (image y points down).
    let e1 = cells[0][1] - cells[0][0];
    let e2 = cells[1][0] - cells[0][0];
    if e1.x * e2.y - e1.y * e2.x < 0.0 {
        cells.reverse();
    }
    // 180-degree ambiguity (boards with an odd + even corner count show it by colour): make
    // the first cell's square darker than its neighbour along the row.
    let centre = |r: usize, c: usize| {
        (cells[r][c] + cells[r][c + 1] + cells[r + 1][c] + cells[r + 1][c + 1]) / 4.0
    };
    let (a, b) = (centre(0, 0), centre(0, 1.min(cols - 2)));
    let bright_first = cols >= 3 && sample(img, w, h, a.x, a.y) > sample(img, w, h, b.x, b.y);
    if bright_first && (board.cols + board.rows) % 2 == 1 {
        cells.reverse();
        for r in cells.iter_mut() {
            r.reverse();
        }
    }
    let mut out = Vec::with_capacity(rows * cols);
    for r in &cells {
        out.extend_from_slice(r);
    }
    out
}
