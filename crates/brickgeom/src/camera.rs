//! Weak-perspective (scaled orthographic) cameras, as in LEGO manuals (DESIGN §4).
//!
//! Conventions, used everywhere in mepnet:
//! - World points are in LDU, y up.
//! - The camera sits on the view sphere at `azimuth` (about +y, from +z towards +x) and
//!   `elevation` (above the xz plane) and looks at the origin; `roll` turns the image about the
//!   view axis (counter-clockwise). Image axes: `u` to the right, `v` up.
//! - Normalised device coordinates: `ndc = scale * (u, v) + translation`, the image spanning
//!   [-1, 1] on both axes (scale in NDC per LDU).
//! - Pixels: column `px = (ndc_x + 1) * width / 2`, row `py = (1 - ndc_y) * height / 2`, with
//!   (0, 0) the top-left *corner* of the image: the centre of pixel (i, j) is (i + 0.5, j + 0.5).
//! - Depth: distance along the view axis away from the camera (larger = farther), in LDU.

use nalgebra::{Matrix2x4, Matrix3, Vector3};

use crate::error::{BrickGeomError, Result};

/// A weak-perspective camera.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Camera {
    /// Degrees above the ground plane.
    pub elevation: f64,
    /// Degrees about +y, from +z towards +x.
    pub azimuth: f64,
    /// Degrees of image rotation about the view axis.
    pub roll: f64,
    /// NDC units per LDU.
    pub scale: f64,
    /// NDC offset `(tx, ty)`.
    pub translation: [f64; 2],
}

impl Camera {
    /// A camera; rejects non-finite values and a non-positive scale.
    pub fn new(
        elevation: f64,
        azimuth: f64,
        roll: f64,
        scale: f64,
        translation: [f64; 2],
    ) -> Result<Self> {
        let c = Camera {
            elevation,
            azimuth,
            roll,
            scale,
            translation,
        };
        c.validate()?;
        Ok(c)
    }

    /// Check the parameters: all finite, scale > 0, elevation within [-90, 90].
    pub fn validate(&self) -> Result<()> {
        let vals = [
            self.elevation,
            self.azimuth,
            self.roll,
            self.scale,
            self.translation[0],
            self.translation[1],
        ];
        if vals.iter().any(|v| !v.is_finite()) {
            return Err(BrickGeomError::InvalidArgument(format!(
                "camera has a non-finite parameter: {self:?}"
            )));
        }
        if self.scale <= 0.0 || self.scale > 1e3 {
            return Err(BrickGeomError::InvalidArgument(format!(
                "camera scale must be in (0, 1000] NDC per LDU, got {}",
                self.scale
            )));
        }
        if self.elevation.abs() > 90.0 {
            return Err(BrickGeomError::InvalidArgument(format!(
                "camera elevation must be within [-90, 90] degrees, got {}",
                self.elevation
            )));
        }
        Ok(())
    }

    /// Rotation from world to camera axes: rows are `u` (right), `v` (up) and the view
    /// direction `w` (from the camera into the scene).
    pub fn rotation(&self) -> Matrix3<f64> {
        let (el, az, roll) = (
            self.elevation.to_radians(),
            self.azimuth.to_radians(),
            self.roll.to_radians(),
        );
        // Camera position direction on the unit sphere.
        let eye = Vector3::new(el.cos() * az.sin(), el.sin(), el.cos() * az.cos());
        let w = -eye;
        // Right vector: horizontal, perpendicular to the view (well defined for |el| < 90).
        let right = Vector3::new(az.cos(), 0.0, -az.sin());
        let up = right.cross(&w).normalize();
        let (cr, sr) = (roll.cos(), roll.sin());
        let u = right * cr + up * sr;
        let v = -right * sr + up * cr;
        Matrix3::from_rows(&[u.transpose(), v.transpose(), w.transpose()])
    }

    /// The 2x4 projection from homogeneous world points (LDU) to NDC.
    pub fn ndc_matrix(&self) -> Matrix2x4<f64> {
        let r = self.rotation();
        let s = self.scale;
        Matrix2x4::new(
            s * r[(0, 0)],
            s * r[(0, 1)],
            s * r[(0, 2)],
            self.translation[0],
            s * r[(1, 0)],
            s * r[(1, 1)],
            s * r[(1, 2)],
            self.translation[1],
        )
    }

    /// The 2x4 projection from homogeneous world points (LDU) to pixel coordinates.
    pub fn pixel_matrix(&self, width: u32, height: u32) -> Matrix2x4<f64> {
        let n = self.ndc_matrix();
        let (hw, hh) = (width as f64 / 2.0, height as f64 / 2.0);
        let mut p = Matrix2x4::zeros();
        for j in 0..4 {
            p[(0, j)] = n[(0, j)] * hw;
            p[(1, j)] = -n[(1, j)] * hh;
        }
        p[(0, 3)] += hw;
        p[(1, 3)] += hh;
        p
    }

    /// Project a world point to pixel coordinates `(px, py)` and depth.
    pub fn project(&self, p: [f64; 3], width: u32, height: u32) -> ([f64; 2], f64) {
        let m = self.pixel_matrix(width, height);
        let x = Vector3::new(p[0], p[1], p[2]);
        let px = m[(0, 0)] * x[0] + m[(0, 1)] * x[1] + m[(0, 2)] * x[2] + m[(0, 3)];
        let py = m[(1, 0)] * x[0] + m[(1, 1)] * x[1] + m[(1, 2)] * x[2] + m[(1, 3)];
        let depth = self.rotation().row(2).dot(&x.transpose());
        ([px, py], depth)
    }

    /// A copy whose scale and translation make the given points fill `fill` (0..1] of the
    /// frame, centred.
    pub fn fitted(&self, points: &[[f64; 3]], fill: f64) -> Result<Camera> {
        if points.is_empty() {
            return Err(BrickGeomError::InvalidArgument(
                "cannot fit a camera to an empty shape".into(),
            ));
        }
        if !(fill > 0.0 && fill <= 1.0) {
            return Err(BrickGeomError::InvalidArgument(format!(
                "fill must be in (0, 1], got {fill}"
            )));
        }
        let r = self.rotation();
        let (mut lo, mut hi) = ([f64::MAX; 2], [f64::MIN; 2]);
        for p in points {
            let x = Vector3::new(p[0], p[1], p[2]);
            for a in 0..2 {
                let c = r.row(a).dot(&x.transpose());
                lo[a] = lo[a].min(c);
                hi[a] = hi[a].max(c);
            }
        }
        let extent = (hi[0] - lo[0]).max(hi[1] - lo[1]).max(1e-6);
        let scale = 2.0 * fill / extent;
        let mut c = *self;
        c.scale = scale;
        c.translation = [
            -scale * (lo[0] + hi[0]) / 2.0,
            -scale * (lo[1] + hi[1]) / 2.0,
        ];
        c.validate()?;
        Ok(c)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cam() -> Camera {
        Camera::new(30.0, 225.0, 0.0, 0.01, [0.0, 0.0]).unwrap()
    }

    #[test]
    fn rotation_is_orthonormal_with_depth_into_the_scene() {
        for (el, az, roll) in [(30.0, 225.0, 0.0), (-20.0, 10.0, 15.0), (89.0, 0.0, -30.0)] {
            let r = Camera::new(el, az, roll, 1.0, [0.0, 0.0])
                .unwrap()
                .rotation();
            let i = r * r.transpose();
            assert!((i - Matrix3::identity()).norm() < 1e-9);
            // u right, v up, w into the scene: a left-handed frame (u x v points at the camera)
            assert!((r.determinant() + 1.0).abs() < 1e-9);
            let eye = -r.row(2).transpose();
            assert!((r.row(0).transpose().cross(&r.row(1).transpose()) - eye).norm() < 1e-9);
        }
    }

    #[test]
    fn known_points() {
        // Looking straight down the -z axis (azimuth 0 = camera on +z), no elevation.
        let c = Camera::new(0.0, 0.0, 0.0, 0.01, [0.0, 0.0]).unwrap();
        let ([px, py], d) = c.project([0.0, 0.0, 0.0], 200, 100);
        assert_eq!((px, py, d), (100.0, 50.0, 0.0));
        // +x goes right, +y goes up (smaller row), +z comes towards the camera.
        let ([px, py], d) = c.project([50.0, 20.0, 10.0], 200, 100);
        assert!((px - 150.0).abs() < 1e-9 && (py - 40.0).abs() < 1e-9 && (d + 10.0).abs() < 1e-9);
    }

    #[test]
    fn fitted_frames_the_points() {
        let pts = [[-40.0, 0.0, -20.0], [40.0, 24.0, 20.0], [0.0, 100.0, 0.0]];
        let c = cam().fitted(&pts, 0.8).unwrap();
        let mut lo = [f64::MAX; 2];
        let mut hi = [f64::MIN; 2];
        for p in pts {
            let (q, _) = c.project(p, 256, 256);
            for a in 0..2 {
                lo[a] = lo[a].min(q[a]);
                hi[a] = hi[a].max(q[a]);
            }
        }
        let span = (hi[0] - lo[0]).max(hi[1] - lo[1]);
        assert!((span - 0.8 * 256.0).abs() < 1e-6);
        assert!(((lo[0] + hi[0]) / 2.0 - 128.0).abs() < 1e-6);
        assert!(((lo[1] + hi[1]) / 2.0 - 128.0).abs() < 1e-6);
    }

    #[test]
    fn bad_cameras_are_rejected() {
        assert!(Camera::new(f64::NAN, 0.0, 0.0, 1.0, [0.0, 0.0]).is_err());
        assert!(Camera::new(0.0, 0.0, 0.0, 0.0, [0.0, 0.0]).is_err());
        assert!(Camera::new(0.0, 0.0, 0.0, 1.0, [f64::INFINITY, 0.0]).is_err());
        assert!(cam().fitted(&[], 0.5).is_err());
    }
}
