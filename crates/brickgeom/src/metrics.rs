//! Geometric evaluation metrics (DESIGN §7): exact nearest-neighbour distances between point
//! sets, the Chamfer distance, and minimum-cost assignment (Hungarian / Kuhn–Munkres).
//!
//! Everything here is deterministic: parallel loops only map independent items and collect in
//! input order, and sums are accumulated in `f64` in input order.

use rayon::prelude::*;

use crate::error::{BrickGeomError, Result};

/// A uniform grid over a point set: the points sorted by cell (counting sort), so that the
/// points of one cell are contiguous.
struct Grid {
    min: [f64; 3],
    /// Cell edge length (> 0).
    h: f64,
    dims: [usize; 3],
    /// `start[c]..start[c + 1]` indexes `points` for cell `c` (x fastest, then y, then z).
    start: Vec<usize>,
    points: Vec<[f32; 3]>,
}

impl Grid {
    /// Grid with about one to two points per cell (at most `2 n` cells), whatever the shape of
    /// the bounding box (flat and degenerate boxes included).
    fn new(pts: &[[f32; 3]]) -> Grid {
        let n = pts.len();
        let mut min = [f64::INFINITY; 3];
        let mut max = [f64::NEG_INFINITY; 3];
        for p in pts {
            for i in 0..3 {
                min[i] = min[i].min(p[i] as f64);
                max[i] = max[i].max(p[i] as f64);
            }
        }
        let ext: [f64; 3] = std::array::from_fn(|i| max[i] - min[i]);
        let max_ext = ext[0].max(ext[1]).max(ext[2]);
        let target = (2 * n).max(1) as f64;
        let cells = |h: f64| -> f64 {
            ext.iter()
                .map(|&e| ((e / h).floor() + 1.0).max(1.0))
                .product()
        };
        // The smallest cell size (to relative precision) whose grid has at most `target` cells:
        // bisection in log space, the cell count being non-increasing in h.
        let h = if max_ext <= 0.0 {
            1.0
        } else {
            let mut hi = max_ext * 1.000_001; // one cell along every axis
            let mut lo = max_ext / target; // too many cells (or exactly target along one axis)
            if cells(lo) <= target {
                hi = lo;
            } else {
                for _ in 0..60 {
                    let mid = (lo * hi).sqrt();
                    if cells(mid) <= target {
                        hi = mid;
                    } else {
                        lo = mid;
                    }
                }
            }
            hi
        };
        let dims: [usize; 3] = std::array::from_fn(|i| ((ext[i] / h).floor() as usize + 1).max(1));
        let mut grid = Grid {
            min,
            h,
            dims,
            start: vec![0; dims[0] * dims[1] * dims[2] + 1],
            points: Vec::with_capacity(n),
        };
        let ids: Vec<usize> = pts.iter().map(|p| grid.cell_id(grid.cell_of(p))).collect();
        for &c in &ids {
            grid.start[c + 1] += 1;
        }
        for c in 0..grid.start.len() - 1 {
            grid.start[c + 1] += grid.start[c];
        }
        let mut next = grid.start.clone();
        let mut sorted = vec![[0.0f32; 3]; n];
        for (p, &c) in pts.iter().zip(&ids) {
            sorted[next[c]] = *p;
            next[c] += 1;
        }
        grid.points = sorted;
        grid
    }

    /// The cell containing `p`, clamped into the grid (points outside the box of the grid map
    /// to the nearest boundary cell).
    fn cell_of(&self, p: &[f32; 3]) -> [usize; 3] {
        std::array::from_fn(|i| {
            let f = ((p[i] as f64 - self.min[i]) / self.h).floor();
            if f <= 0.0 {
                0
            } else {
                (f as usize).min(self.dims[i] - 1)
            }
        })
    }

    fn cell_id(&self, c: [usize; 3]) -> usize {
        c[0] + self.dims[0] * (c[1] + self.dims[1] * c[2])
    }

    /// Squared distance (computed in f32 as `dx² + dy² + dz²`) from `p` to its nearest grid
    /// point: visit cubic shells of cells around `p`'s cell until no unvisited cell can hold a
    /// nearer point.
    fn nearest_sq(&self, p: &[f32; 3]) -> f32 {
        let c = self.cell_of(p);
        let mut best = f32::INFINITY;
        let mut r = 0usize;
        loop {
            // Visit the cells at Chebyshev distance exactly r from c.
            let lo: [usize; 3] = std::array::from_fn(|i| c[i].saturating_sub(r));
            let hi: [usize; 3] = std::array::from_fn(|i| (c[i] + r).min(self.dims[i] - 1));
            for z in lo[2]..=hi[2] {
                let z_on = z.abs_diff(c[2]) == r;
                for y in lo[1]..=hi[1] {
                    let yz_on = z_on || y.abs_diff(c[1]) == r;
                    if yz_on {
                        for x in lo[0]..=hi[0] {
                            best = best.min(self.scan_cell([x, y, z], p));
                        }
                    } else {
                        // Only the two x-ends of this row lie on the shell.
                        if c[0] >= r {
                            best = best.min(self.scan_cell([c[0] - r, y, z], p));
                        }
                        if r > 0 && c[0] + r < self.dims[0] {
                            best = best.min(self.scan_cell([c[0] + r, y, z], p));
                        }
                    }
                }
            }
            // Lower bound on the distance to any point in a cell outside the visited box: the
            // distance from p to the nearest face of the box that is not a face of the grid.
            let mut bound = f64::INFINITY;
            for i in 0..3 {
                let pi = p[i] as f64;
                if lo[i] > 0 {
                    let face = self.min[i] + lo[i] as f64 * self.h;
                    bound = bound.min((pi - face).max(0.0));
                }
                if hi[i] + 1 < self.dims[i] {
                    let face = self.min[i] + (hi[i] + 1) as f64 * self.h;
                    bound = bound.min((face - pi).max(0.0));
                }
            }
            if bound == f64::INFINITY {
                return best; // the whole grid has been visited
            }
            // A small relative margin keeps the f32 rounding of `best` on the safe side.
            if (best as f64) <= bound * bound * (1.0 - 1e-6) {
                return best;
            }
            r += 1;
        }
    }

    fn scan_cell(&self, cell: [usize; 3], p: &[f32; 3]) -> f32 {
        let id = self.cell_id(cell);
        let mut best = f32::INFINITY;
        for q in &self.points[self.start[id]..self.start[id + 1]] {
            best = best.min(sq_dist(p, q));
        }
        best
    }
}

/// Squared Euclidean distance in f32, always evaluated as `dx*dx + dy*dy + dz*dz`.
#[inline]
fn sq_dist(p: &[f32; 3], q: &[f32; 3]) -> f32 {
    let dx = p[0] - q[0];
    let dy = p[1] - q[1];
    let dz = p[2] - q[2];
    dx * dx + dy * dy + dz * dz
}

fn check_points(pts: &[[f32; 3]], what: &str) -> Result<()> {
    if pts.is_empty() {
        return Err(BrickGeomError::InvalidArgument(format!(
            "{what} point set is empty"
        )));
    }
    if let Some(i) = pts.iter().position(|p| p.iter().any(|v| !v.is_finite())) {
        return Err(BrickGeomError::InvalidArgument(format!(
            "{what} point {i} is not finite: {:?}",
            pts[i]
        )));
    }
    Ok(())
}

/// For each point of `from`, the squared distance to its nearest point of `to` (exact; the
/// value equals the minimum over `to` of `dx² + dy² + dz²` evaluated in f32).
///
/// A uniform grid over `to` (about one to two points per cell) is searched in growing cubic
/// shells until the best distance is proven; the queries run in parallel with rayon and the
/// result is in the order of `from` (deterministic).
///
/// Errors: [`BrickGeomError::InvalidArgument`] if either set is empty or holds a NaN or
/// infinite coordinate.
pub fn nearest_sq_dists(from: &[[f32; 3]], to: &[[f32; 3]]) -> Result<Vec<f32>> {
    check_points(from, "query")?;
    check_points(to, "target")?;
    let grid = Grid::new(to);
    Ok(from.par_iter().map(|p| grid.nearest_sq(p)).collect())
}

/// The (squared) Chamfer distance between two point sets, in the Pixel2Mesh / paper convention:
/// the mean over `a` of the squared distance to the nearest point of `b`, plus the mean over
/// `b` of the squared distance to the nearest point of `a`. Symmetric; 0 for identical sets;
/// in the squared units of the input.
///
/// Sums are accumulated in f64 in input order (deterministic). Errors as
/// [`nearest_sq_dists`].
pub fn chamfer(a: &[[f32; 3]], b: &[[f32; 3]]) -> Result<f64> {
    let ab = nearest_sq_dists(a, b)?;
    let ba = nearest_sq_dists(b, a)?;
    let mean = |d: &[f32]| d.iter().map(|&x| x as f64).sum::<f64>() / d.len() as f64;
    Ok(mean(&ab) + mean(&ba))
}

/// Minimum-cost assignment (Kuhn–Munkres with potentials, O(n² m) for n ≤ m) of an
/// `n x m` cost matrix given as rows of equal length.
///
/// Returns, for each row, the column assigned to it: every row gets a distinct column when
/// `n <= m`; when `n > m` the matrix is solved transposed, exactly `m` rows get a column and
/// the others `None`. The total cost of the assigned pairs is minimal among all assignments of
/// `min(n, m)` pairs. An empty matrix (`n == 0` or `m == 0`) gives all `None`.
///
/// Errors: [`BrickGeomError::InvalidArgument`] for ragged rows or a non-finite cost.
pub fn hungarian(cost: &[Vec<f64>]) -> Result<Vec<Option<usize>>> {
    let n = cost.len();
    let m = cost.first().map_or(0, Vec::len);
    for (i, row) in cost.iter().enumerate() {
        if row.len() != m {
            return Err(BrickGeomError::InvalidArgument(format!(
                "cost matrix is ragged: row {i} has {} entries, row 0 has {m}",
                row.len()
            )));
        }
        if let Some(j) = row.iter().position(|v| !v.is_finite()) {
            return Err(BrickGeomError::InvalidArgument(format!(
                "cost[{i}][{j}] is not finite: {}",
                row[j]
            )));
        }
    }
    if n == 0 || m == 0 {
        return Ok(vec![None; n]);
    }
    if n <= m {
        let col = kuhn_munkres(n, m, |i, j| cost[i][j]);
        Ok(col.into_iter().map(Some).collect())
    } else {
        // Transposed: rows of the transposed problem are the columns of `cost`.
        let row_of_col = kuhn_munkres(m, n, |j, i| cost[i][j]);
        let mut out = vec![None; n];
        for (j, &i) in row_of_col.iter().enumerate() {
            out[i] = Some(j);
        }
        Ok(out)
    }
}

/// The e-maxx formulation of the Hungarian algorithm for `n <= m` (finite costs): returns the
/// column of each row.
fn kuhn_munkres(n: usize, m: usize, a: impl Fn(usize, usize) -> f64) -> Vec<usize> {
    debug_assert!(n <= m);
    // 1-based: row/column 0 is the virtual start.
    let mut u = vec![0.0f64; n + 1];
    let mut v = vec![0.0f64; m + 1];
    let mut p = vec![0usize; m + 1]; // p[j]: row matched to column j (0 = none)
    let mut way = vec![0usize; m + 1];
    for i in 1..=n {
        p[0] = i;
        let mut j0 = 0usize;
        let mut minv = vec![f64::INFINITY; m + 1];
        let mut used = vec![false; m + 1];
        loop {
            used[j0] = true;
            let i0 = p[j0];
            let mut delta = f64::INFINITY;
            let mut j1 = 0usize;
            for j in 1..=m {
                if !used[j] {
                    let cur = a(i0 - 1, j - 1) - u[i0] - v[j];
                    if cur < minv[j] {
                        minv[j] = cur;
                        way[j] = j0;
                    }
                    if minv[j] < delta {
                        delta = minv[j];
                        j1 = j;
                    }
                }
            }
            for j in 0..=m {
                if used[j] {
                    u[p[j]] += delta;
                    v[j] -= delta;
                } else {
                    minv[j] -= delta;
                }
            }
            j0 = j1;
            if p[j0] == 0 {
                break;
            }
        }
        loop {
            let j1 = way[j0];
            p[j0] = p[j1];
            j0 = j1;
            if j0 == 0 {
                break;
            }
        }
    }
    let mut col = vec![0usize; n];
    for j in 1..=m {
        if p[j] != 0 {
            col[p[j] - 1] = j - 1;
        }
    }
    col
}

#[cfg(test)]
mod tests {
    use super::*;

    /// xorshift64*: a tiny deterministic generator for test data.
    struct Rng(u64);
    impl Rng {
        fn next(&mut self) -> u64 {
            self.0 ^= self.0 >> 12;
            self.0 ^= self.0 << 25;
            self.0 ^= self.0 >> 27;
            self.0.wrapping_mul(0x2545_F491_4F6C_DD1D)
        }
        /// Uniform in [0, 1).
        fn unit(&mut self) -> f64 {
            (self.next() >> 11) as f64 / (1u64 << 53) as f64
        }
        fn points(&mut self, n: usize, scale: [f32; 3]) -> Vec<[f32; 3]> {
            (0..n)
                .map(|_| std::array::from_fn(|i| (self.unit() as f32 - 0.5) * scale[i]))
                .collect()
        }
    }

    fn brute_nearest(from: &[[f32; 3]], to: &[[f32; 3]]) -> Vec<f32> {
        from.iter()
            .map(|p| {
                to.iter()
                    .map(|q| sq_dist(p, q))
                    .fold(f32::INFINITY, f32::min)
            })
            .collect()
    }

    fn brute_chamfer(a: &[[f32; 3]], b: &[[f32; 3]]) -> f64 {
        let mean = |d: Vec<f32>| d.iter().map(|&x| x as f64).sum::<f64>() / d.len() as f64;
        mean(brute_nearest(a, b)) + mean(brute_nearest(b, a))
    }

    fn close(a: f64, b: f64, rel: f64) -> bool {
        (a - b).abs() <= rel * a.abs().max(b.abs()).max(1e-30)
    }

    #[test]
    fn chamfer_of_identical_sets_is_zero() {
        let pts = Rng(7).points(300, [10.0, 3.0, 5.0]);
        assert_eq!(chamfer(&pts, &pts).unwrap(), 0.0);
    }

    #[test]
    fn chamfer_of_two_single_points_is_twice_the_squared_distance() {
        let a = [[1.0f32, 2.0, 3.0]];
        let b = [[4.0f32, -2.0, 3.0]];
        assert_eq!(chamfer(&a, &b).unwrap(), 2.0 * 25.0);
    }

    #[test]
    fn nearest_matches_brute_force_on_random_sets() {
        let mut rng = Rng(12345);
        // Boxes of several shapes: cubic, flat, a line, and a query set larger than the target
        // (many queries outside the target's grid).
        let shapes = [
            ([10.0, 10.0, 10.0], [10.0, 10.0, 10.0]),
            ([100.0, 0.0, 50.0], [100.0, 1.0, 50.0]),
            ([1.0, 0.0, 0.0], [1.0, 1e-3, 1e-3]),
            ([1.0, 1.0, 1.0], [40.0, 40.0, 40.0]),
        ];
        for (ta, fa) in shapes {
            for &(nt, nf) in &[(1usize, 50usize), (7, 300), (400, 250), (333, 900)] {
                let to = rng.points(nt, ta);
                let from = rng.points(nf, fa);
                let got = nearest_sq_dists(&from, &to).unwrap();
                let want = brute_nearest(&from, &to);
                for (g, w) in got.iter().zip(&want) {
                    assert!(close(*g as f64, *w as f64, 1e-6), "{g} vs {w}");
                }
                let c = chamfer(&from, &to).unwrap();
                assert!(close(c, brute_chamfer(&from, &to), 1e-6));
            }
        }
    }

    #[test]
    fn nearest_handles_duplicates_and_clusters() {
        let mut rng = Rng(99);
        // A tight cluster far from a few outliers: most grid cells are empty.
        let mut to = rng.points(500, [1e-3, 1e-3, 1e-3]);
        to.push([1000.0, 0.0, 0.0]);
        to.push([0.0, -1000.0, 0.0]);
        to.extend(std::iter::repeat_n([0.5f32, 0.5, 0.5], 20));
        let from = rng.points(200, [2000.0, 2000.0, 2000.0]);
        let got = nearest_sq_dists(&from, &to).unwrap();
        assert_eq!(got, brute_nearest(&from, &to));
    }

    #[test]
    fn translation_by_less_than_half_the_spacing_gives_twice_its_square() {
        // On a lattice of spacing 1 every point's nearest translated point is its own image when
        // |d| < 1/2, so the Chamfer distance is exactly 2 |d|² (up to f32 rounding).
        let mut a = Vec::new();
        for x in 0..8 {
            for y in 0..5 {
                for z in 0..6 {
                    a.push([x as f32, y as f32, z as f32]);
                }
            }
        }
        let d = [0.1f32, -0.05, 0.2];
        let d2 = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]) as f64;
        let b: Vec<[f32; 3]> = a
            .iter()
            .map(|p| [p[0] + d[0], p[1] + d[1], p[2] + d[2]])
            .collect();
        let c = chamfer(&a, &b).unwrap();
        assert!(close(c, 2.0 * d2, 1e-5), "{c} vs {}", 2.0 * d2);
        // For any set and any translation the Chamfer distance is at most 2 |d|².
        let r = Rng(3).points(300, [5.0, 5.0, 5.0]);
        let big = [1.5f32, 0.7, -2.0];
        let rb: Vec<[f32; 3]> = r
            .iter()
            .map(|p| [p[0] + big[0], p[1] + big[1], p[2] + big[2]])
            .collect();
        let bound = 2.0 * (big[0] * big[0] + big[1] * big[1] + big[2] * big[2]) as f64;
        assert!(chamfer(&r, &rb).unwrap() <= bound * (1.0 + 1e-5));
    }

    #[test]
    fn chamfer_is_symmetric_and_deterministic() {
        let mut rng = Rng(5);
        let a = rng.points(700, [3.0, 1.0, 2.0]);
        let b = rng.points(500, [2.0, 2.0, 2.0]);
        let ab = chamfer(&a, &b).unwrap();
        assert_eq!(ab, chamfer(&b, &a).unwrap());
        assert_eq!(ab, chamfer(&a, &b).unwrap());
    }

    #[test]
    fn empty_and_non_finite_inputs_are_errors() {
        let a = [[0.0f32, 0.0, 0.0]];
        assert!(matches!(
            nearest_sq_dists(&[], &a),
            Err(BrickGeomError::InvalidArgument(_))
        ));
        assert!(matches!(
            chamfer(&a, &[]),
            Err(BrickGeomError::InvalidArgument(_))
        ));
        let bad = [[0.0f32, f32::NAN, 0.0]];
        assert!(matches!(
            chamfer(&a, &bad),
            Err(BrickGeomError::InvalidArgument(_))
        ));
        let inf = [[f32::INFINITY, 0.0, 0.0]];
        assert!(matches!(
            chamfer(&inf, &a),
            Err(BrickGeomError::InvalidArgument(_))
        ));
    }

    fn permutations(k: usize, m: usize) -> Vec<Vec<usize>> {
        // All injective maps from 0..k into 0..m.
        if k == 0 {
            return vec![vec![]];
        }
        let mut out = Vec::new();
        for prefix in permutations(k - 1, m) {
            for j in 0..m {
                if !prefix.contains(&j) {
                    let mut p = prefix.clone();
                    p.push(j);
                    out.push(p);
                }
            }
        }
        out
    }

    fn brute_assignment_cost(cost: &[Vec<f64>]) -> f64 {
        let n = cost.len();
        let m = cost[0].len();
        if n <= m {
            permutations(n, m)
                .iter()
                .map(|p| p.iter().enumerate().map(|(i, &j)| cost[i][j]).sum::<f64>())
                .fold(f64::INFINITY, f64::min)
        } else {
            permutations(m, n)
                .iter()
                .map(|p| p.iter().enumerate().map(|(j, &i)| cost[i][j]).sum::<f64>())
                .fold(f64::INFINITY, f64::min)
        }
    }

    fn check_assignment(cost: &[Vec<f64>]) {
        let n = cost.len();
        let m = cost[0].len();
        let asg = hungarian(cost).unwrap();
        assert_eq!(asg.len(), n);
        let cols: Vec<usize> = asg.iter().flatten().copied().collect();
        assert_eq!(cols.len(), n.min(m));
        let mut uniq = cols.clone();
        uniq.sort_unstable();
        uniq.dedup();
        assert_eq!(uniq.len(), cols.len(), "columns must be distinct");
        assert!(cols.iter().all(|&j| j < m));
        let total: f64 = asg
            .iter()
            .enumerate()
            .filter_map(|(i, j)| j.map(|j| cost[i][j]))
            .sum();
        let best = brute_assignment_cost(cost);
        assert!(close(total, best, 1e-9), "{total} vs {best}");
    }

    #[test]
    fn hungarian_matches_brute_force() {
        let mut rng = Rng(2024);
        for &(n, m) in &[(5, 5), (4, 6), (6, 4), (1, 5), (5, 1), (3, 3), (2, 7)] {
            for trial in 0..30 {
                let cost: Vec<Vec<f64>> = (0..n)
                    .map(|_| {
                        (0..m)
                            .map(|_| {
                                if trial % 3 == 0 {
                                    // Many ties.
                                    (rng.unit() * 4.0).floor()
                                } else {
                                    rng.unit() * 200.0 - 100.0
                                }
                            })
                            .collect()
                    })
                    .collect();
                check_assignment(&cost);
            }
        }
    }

    #[test]
    fn hungarian_edge_cases() {
        assert_eq!(hungarian(&[]).unwrap(), Vec::<Option<usize>>::new());
        assert_eq!(hungarian(&[vec![], vec![]]).unwrap(), vec![None, None]);
        assert_eq!(hungarian(&[vec![3.0]]).unwrap(), vec![Some(0)]);
        // The identity is not optimal here.
        let c = vec![vec![1.0, 0.0], vec![0.0, 1.0]];
        assert_eq!(hungarian(&c).unwrap(), vec![Some(1), Some(0)]);
        assert!(matches!(
            hungarian(&[vec![1.0, 2.0], vec![1.0]]),
            Err(BrickGeomError::InvalidArgument(_))
        ));
        assert!(matches!(
            hungarian(&[vec![1.0, f64::NAN]]),
            Err(BrickGeomError::InvalidArgument(_))
        ));
    }
}
