//! Triangle meshes in LDU, y up, used for rendering and Chamfer distance.

use crate::lattice::Pose;

/// An indexed triangle mesh. Vertices in LDU with y up (brickgeom's frame, not LDraw's).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Mesh {
    pub vertices: Vec<[f32; 3]>,
    pub triangles: Vec<[u32; 3]>,
}

impl Mesh {
    /// An empty mesh.
    pub fn new() -> Self {
        Mesh::default()
    }

    /// Append another mesh (indices are offset).
    pub fn append(&mut self, other: &Mesh) {
        let base = self.vertices.len() as u32;
        self.vertices.extend_from_slice(&other.vertices);
        self.triangles.extend(
            other
                .triangles
                .iter()
                .map(|t| [t[0] + base, t[1] + base, t[2] + base]),
        );
    }

    /// The mesh moved by a lattice pose.
    pub fn transformed(&self, pose: &Pose) -> Mesh {
        Mesh {
            vertices: self.vertices.iter().map(|v| pose.apply_ldu(*v)).collect(),
            triangles: self.triangles.clone(),
        }
    }

    /// Axis-aligned bounds `(min, max)`; `None` for an empty mesh.
    pub fn bounds(&self) -> Option<([f32; 3], [f32; 3])> {
        let first = *self.vertices.first()?;
        let mut lo = first;
        let mut hi = first;
        for v in &self.vertices {
            for a in 0..3 {
                lo[a] = lo[a].min(v[a]);
                hi[a] = hi[a].max(v[a]);
            }
        }
        Some((lo, hi))
    }

    /// Total surface area (LDU²).
    pub fn area(&self) -> f32 {
        self.triangles
            .iter()
            .map(|t| {
                let a = self.vertices[t[0] as usize];
                let b = self.vertices[t[1] as usize];
                let c = self.vertices[t[2] as usize];
                let u = [b[0] - a[0], b[1] - a[1], b[2] - a[2]];
                let v = [c[0] - a[0], c[1] - a[1], c[2] - a[2]];
                let n = [
                    u[1] * v[2] - u[2] * v[1],
                    u[2] * v[0] - u[0] * v[2],
                    u[0] * v[1] - u[1] * v[0],
                ];
                0.5 * (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt()
            })
            .sum()
    }
}
