//! The lattice (DESIGN §2): x and z in half-studs (10 LDU), y in plates (8 LDU), y up.
//!
//! A voxel (i, j, k) covers LDU [10i, 10i+10) x [8j, 8j+8) x [10k, 10k+10). Points (studs,
//! anti-studs, translations) are lattice points, i.e. voxel corners. A pose is a yaw in quarter
//! turns about +y through the component origin, then an integer lattice translation.

/// An integer lattice point or voxel index, `[x, y, z]`.
pub type Lattice = [i32; 3];

/// LDU per lattice unit along x, y, z.
pub const LDU_PER_UNIT: [f32; 3] = [10.0, 8.0, 10.0];

/// Largest |coordinate| (in lattice units) accepted anywhere; beyond this input is "absurd".
/// 4096 half-studs is 20 m of LEGO, far more than any real model.
pub const COORD_LIMIT: i32 = 4096;

/// A rigid placement on the lattice: `yaw` quarter turns about +y, then translation `t`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Default)]
pub struct Pose {
    pub yaw: u8,
    pub t: Lattice,
}

impl Pose {
    /// A pose; `yaw` is taken modulo 4.
    pub fn new(yaw: u8, t: Lattice) -> Self {
        Pose { yaw: yaw % 4, t }
    }

    /// The identity pose.
    pub fn identity() -> Self {
        Pose::default()
    }

    /// Apply to a lattice point (stud, anti-stud, origin).
    pub fn apply_point(&self, p: Lattice) -> Lattice {
        let r = rotate_point(p, self.yaw);
        [r[0] + self.t[0], r[1] + self.t[1], r[2] + self.t[2]]
    }

    /// Apply to a voxel index (the cell moves as a whole).
    pub fn apply_cell(&self, c: Lattice) -> Lattice {
        let r = rotate_cell(c, self.yaw);
        [r[0] + self.t[0], r[1] + self.t[1], r[2] + self.t[2]]
    }

    /// Apply to a point in LDU (y up), e.g. a mesh vertex.
    pub fn apply_ldu(&self, p: [f32; 3]) -> [f32; 3] {
        let r = rotate_ldu(p, self.yaw);
        [
            r[0] + self.t[0] as f32 * LDU_PER_UNIT[0],
            r[1] + self.t[1] as f32 * LDU_PER_UNIT[1],
            r[2] + self.t[2] as f32 * LDU_PER_UNIT[2],
        ]
    }

    /// `self ∘ inner`: first `inner`, then `self`.
    pub fn compose(&self, inner: &Pose) -> Pose {
        Pose {
            yaw: (self.yaw + inner.yaw) % 4,
            t: self.apply_point(inner.t),
        }
    }

    /// The 3x3 rotation matrix (row major) in the lattice frame. LDraw's frame turns the other
    /// way about y (see `ldraw::ldraw_placement`).
    pub fn rotation_matrix(&self) -> [[f32; 3]; 3] {
        yaw_matrix(self.yaw)
    }
}

/// Rotation about +y by `yaw` quarter turns: R_y(90°) maps (x, y, z) to (z, y, -x).
pub fn rotate_point(p: Lattice, yaw: u8) -> Lattice {
    let [x, y, z] = p;
    match yaw % 4 {
        0 => [x, y, z],
        1 => [z, y, -x],
        2 => [-x, y, -z],
        _ => [-z, y, x],
    }
}

/// Rotation of a voxel index: the unit cell with min corner c rotates to the cell whose min
/// corner is the rotated cell's min corner.
pub fn rotate_cell(c: Lattice, yaw: u8) -> Lattice {
    let [i, j, k] = c;
    match yaw % 4 {
        0 => [i, j, k],
        1 => [k, j, -i - 1],
        2 => [-i - 1, j, -k - 1],
        _ => [-k - 1, j, i],
    }
}

/// Rotation of a float point (LDU or lattice units alike).
pub fn rotate_ldu(p: [f32; 3], yaw: u8) -> [f32; 3] {
    let [x, y, z] = p;
    match yaw % 4 {
        0 => [x, y, z],
        1 => [z, y, -x],
        2 => [-x, y, -z],
        _ => [-z, y, x],
    }
}

/// Row-major matrix of `rotate_point`.
pub fn yaw_matrix(yaw: u8) -> [[f32; 3]; 3] {
    match yaw % 4 {
        0 => [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
        1 => [[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]],
        2 => [[-1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, -1.0]],
        _ => [[0.0, 0.0, -1.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0]],
    }
}

/// The yaw whose matrix equals `m` (within `tol`), if `m` is a pure yaw rotation.
pub fn yaw_from_matrix(m: &[[f32; 3]; 3], tol: f32) -> Option<u8> {
    (0..4u8).find(|&yaw| {
        let r = yaw_matrix(yaw);
        (0..3).all(|i| (0..3).all(|j| (m[i][j] - r[i][j]).abs() <= tol))
    })
}

/// Lattice point to LDU (y up).
pub fn lattice_to_ldu(p: Lattice) -> [f32; 3] {
    [
        p[0] as f32 * LDU_PER_UNIT[0],
        p[1] as f32 * LDU_PER_UNIT[1],
        p[2] as f32 * LDU_PER_UNIT[2],
    ]
}

/// Check a point is within the supported range.
pub fn check_range(p: Lattice) -> crate::Result<()> {
    if p.iter().all(|c| c.abs() <= COORD_LIMIT) {
        Ok(())
    } else {
        Err(crate::BrickGeomError::OutOfRange {
            pos: p,
            limit: COORD_LIMIT,
        })
    }
}

/// Pack a lattice point (|coordinates| < 2^20) into one u64 key for hashing.
#[inline]
pub fn pack(p: Lattice) -> u64 {
    const B: i64 = 1 << 20;
    let f = |v: i32| ((v as i64 + B) as u64) & 0x1f_ffff;
    (f(p[0]) << 42) | (f(p[1]) << 21) | f(p[2])
}

/// A fast multiplicative hasher for packed lattice keys (the std SipHash is a large share of a
/// connection check otherwise). Not DoS-resistant, which does not matter for geometry.
#[derive(Default, Clone, Copy)]
pub struct PointHasher(u64);

impl std::hash::Hasher for PointHasher {
    #[inline]
    fn finish(&self) -> u64 {
        self.0
    }
    #[inline]
    fn write(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.write_u64(b as u64);
        }
    }
    #[inline]
    fn write_u64(&mut self, v: u64) {
        self.0 = (self.0.rotate_left(5) ^ v).wrapping_mul(0x517c_c1b7_2722_0a95);
    }
}

/// Hash map keyed by packed lattice points.
pub type PointMap<V> =
    std::collections::HashMap<u64, V, std::hash::BuildHasherDefault<PointHasher>>;
/// Hash set of packed lattice points.
pub type PointSet = std::collections::HashSet<u64, std::hash::BuildHasherDefault<PointHasher>>;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cell_rotation_matches_point_rotation_of_cell_centre() {
        for yaw in 0..4u8 {
            for c in [[0, 0, 0], [3, 1, -2], [-5, 2, 7]] {
                let centre = [
                    2.0 * c[0] as f32 + 1.0,
                    c[1] as f32,
                    2.0 * c[2] as f32 + 1.0,
                ];
                let rc = rotate_cell(c, yaw);
                let rcentre = rotate_ldu(centre, yaw);
                assert_eq!(rcentre[0], 2.0 * rc[0] as f32 + 1.0);
                assert_eq!(rcentre[2], 2.0 * rc[2] as f32 + 1.0);
            }
        }
    }

    #[test]
    fn matrix_round_trip() {
        for yaw in 0..4u8 {
            assert_eq!(yaw_from_matrix(&yaw_matrix(yaw), 1e-4), Some(yaw));
        }
    }
}
