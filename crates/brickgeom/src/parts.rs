//! The part table (PLACEHOLDER: a few rectangular parts; the full 72-part table replaces this).

use crate::library::{Category, PartDef};
use crate::mesh::Mesh;

/// Aliases used in real files -> canonical library ids.
pub const ALIASES: &[(&str, &str)] = &[("3001old", "3001")];

fn rect(id: &'static str, name: &'static str, w: i32, l: i32, h: i32) -> PartDef {
    // w studs along z, l studs along x, h plates tall; origin top centre.
    let mut voxels = Vec::new();
    for x in -l..l {
        for z in -w..w {
            for y in -h..0 {
                voxels.push([x, y, z]);
            }
        }
    }
    let mut studs = Vec::new();
    let mut anti = Vec::new();
    for i in 0..l {
        for k in 0..w {
            studs.push([-l + 1 + 2 * i, 0, -w + 1 + 2 * k]);
            anti.push([-l + 1 + 2 * i, -h, -w + 1 + 2 * k]);
        }
    }
    let mut mesh = Mesh::new();
    let (x0, x1, z0, z1, y0) = (
        -10.0 * l as f32,
        10.0 * l as f32,
        -10.0 * w as f32,
        10.0 * w as f32,
        -8.0 * h as f32,
    );
    mesh.vertices = vec![
        [x0, y0, z0],
        [x1, y0, z0],
        [x1, y0, z1],
        [x0, y0, z1],
        [x0, 0.0, z0],
        [x1, 0.0, z0],
        [x1, 0.0, z1],
        [x0, 0.0, z1],
    ];
    mesh.triangles = vec![
        [0, 2, 1],
        [0, 3, 2],
        [4, 5, 6],
        [4, 6, 7],
        [0, 1, 5],
        [0, 5, 4],
        [1, 2, 6],
        [1, 6, 5],
        [2, 3, 7],
        [2, 7, 6],
        [3, 0, 4],
        [3, 4, 7],
    ];
    PartDef {
        id,
        name,
        category: Category::Simple,
        voxels,
        studs,
        anti_studs: anti,
        symmetry: if w == l { 4 } else { 2 },
        keypoint: [0.0, 0.0, 0.0],
        mesh,
    }
}

/// Build every part of the table.
pub fn build_parts() -> Vec<PartDef> {
    vec![
        rect("3001", "Brick  2 x  4", 2, 4, 3),
        rect("3003", "Brick  2 x  2", 2, 2, 3),
        rect("3005", "Brick  1 x  1", 1, 1, 3),
        rect("3024", "Plate  1 x  1", 1, 1, 1),
        rect("3022", "Plate  2 x  2", 2, 2, 1),
        rect("3020", "Plate  2 x  4", 2, 4, 1),
        rect("3004", "Brick  1 x  2", 1, 2, 3),
    ]
}
