//! Conversion between LDraw placements (y-down LDU, 3x3 matrix) and lattice poses (y up).
//!
//! The frame change is the rotation `C = diag(1, -1, -1)` (half a turn about x; determinant +1,
//! never a mirror, DESIGN §2): LDraw (x, y, z) LDU is lattice LDU (x, -y, -z). A rotation `M`
//! in LDraw's frame is `C M C` in the lattice frame; for a turn about y this reverses its sense,
//! so LDraw's yaw `k` quarter turns is the lattice's yaw `-k`.

use crate::lattice::{yaw_from_matrix, yaw_matrix, Pose};

/// A lattice pose recovered from an LDraw placement, with flags for what did not fit.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct LatticePose {
    /// Nearest lattice pose (yaw 0 when the rotation is not a yaw).
    pub pose: Pose,
    /// The position is more than 0.05 LDU from the lattice point on some axis.
    pub off_lattice: bool,
    /// The matrix is not one of the four yaw rotations (within 1e-3).
    pub non_yaw: bool,
}

/// Convert an LDraw placement (y-down LDU position, matrix) to the y-up lattice:
/// translation `round(x / 10, -y / 8, -z / 10)`, yaw the matrix's turn about y reversed.
pub fn lattice_pose(position: [f64; 3], matrix: [[f64; 3]; 3]) -> LatticePose {
    let scaled = [position[0] / 10.0, -position[1] / 8.0, -position[2] / 10.0];
    let unit = [10.0, 8.0, 10.0];
    let mut t = [0i32; 3];
    let mut off_lattice = false;
    for a in 0..3 {
        let r = scaled[a].round();
        // `as` saturates (and maps NaN to 0); such inputs are flagged off-lattice below.
        t[a] = r as i32;
        let residual = (scaled[a] - t[a] as f64) * unit[a];
        off_lattice |= residual.is_nan() || residual.abs() > 0.05;
    }
    let m32 = matrix.map(|row| row.map(|v| v as f32));
    let yaw = yaw_from_matrix(&m32, 1e-3).map(|k| (4 - k) % 4);
    LatticePose {
        pose: Pose::new(yaw.unwrap_or(0), t),
        off_lattice,
        non_yaw: yaw.is_none(),
    }
}

/// The LDraw placement (y-down LDU position, matrix) of a lattice pose; inverse of
/// [`lattice_pose`].
pub fn ldraw_placement(pose: Pose) -> ([f64; 3], [[f64; 3]; 3]) {
    let position = [
        f64::from(pose.t[0]) * 10.0,
        -f64::from(pose.t[1]) * 8.0 + 0.0,
        -f64::from(pose.t[2]) * 10.0 + 0.0,
    ];
    let ldraw_yaw = (4 - pose.yaw % 4) % 4;
    (
        position,
        yaw_matrix(ldraw_yaw).map(|row| row.map(f64::from)),
    )
}
