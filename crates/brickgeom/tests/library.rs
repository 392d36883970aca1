//! The 72-part library (DESIGN §3): table, occupancy, connection points, symmetry, meshes.

use std::collections::{BTreeSet, HashSet};

use brickgeom::lattice::{rotate_cell, rotate_ldu, rotate_point, Lattice};
use brickgeom::{library, Category, PartDef};

/// (id, category, voxels, studs, anti-studs, symmetry), worked out by hand from the LDraw
/// geometry and the occupancy rule (a cell is occupied when more than half of it is body).
const EXPECTED: &[(&str, Category, usize, usize, usize, u8)] = {
    use Category::*;
    &[
        ("3024", Simple, 4, 1, 1, 4),
        ("3005", Simple, 12, 1, 1, 4),
        ("3023", Simple, 8, 2, 3, 2),
        ("3004", Simple, 24, 2, 3, 2),
        ("3623", Simple, 12, 3, 5, 2),
        ("3622", Simple, 36, 3, 5, 2),
        ("3010", Simple, 48, 4, 7, 2),
        ("3666", Simple, 24, 6, 11, 2),
        ("3009", Simple, 72, 6, 11, 2),
        ("3460", Simple, 32, 8, 15, 2),
        ("3008", Simple, 96, 8, 15, 2),
        ("3022", Simple, 16, 4, 5, 4),
        ("3003", Simple, 48, 4, 5, 4),
        ("3021", Simple, 24, 6, 8, 2),
        ("3020", Simple, 32, 8, 11, 2),
        ("3001", Simple, 96, 8, 11, 2),
        ("3795", Simple, 48, 12, 17, 2),
        ("2456", Simple, 144, 12, 17, 2),
        ("3034", Simple, 64, 16, 23, 2),
        ("3007", Simple, 192, 16, 23, 2),
        ("3036", Simple, 192, 48, 83, 2),
        ("41539", Simple, 256, 64, 113, 4),
        ("3958", Simple, 144, 36, 61, 4),
        ("3033", Simple, 240, 60, 105, 2),
        ("3002", Simple, 72, 6, 8, 2),
        ("2445", Simple, 96, 24, 35, 2),
        ("3030", Simple, 160, 40, 67, 2),
        ("3031", Simple, 64, 16, 25, 4),
        ("3032", Simple, 96, 24, 39, 2),
        ("3035", Simple, 128, 32, 53, 2),
        ("3710", Simple, 16, 4, 7, 2),
        ("3832", Simple, 80, 20, 29, 2),
        ("4073", Simple, 4, 1, 1, 4),
        ("4477", Simple, 40, 10, 19, 2),
        ("6112", Simple, 144, 12, 23, 2),
        ("3062b", Simple, 12, 1, 1, 4),
        ("3245a", Simple, 48, 2, 3, 2),
        // Round 2x2: the corner cells are only 31% inside the circle.
        ("4032a", Simple, 12, 4, 5, 4),
        ("60479", Simple, 48, 12, 23, 2),
        ("4282", Simple, 128, 32, 47, 2),
        ("22886", Simple, 72, 2, 3, 2),
        ("3941", Simple, 36, 4, 5, 4),
        ("2877", Simple, 24, 2, 3, 1), // its two long faces are ridged differently
        // Cone: the top plate layer is only 41% inside the cone.
        ("59900", Simple, 8, 1, 1, 4),
        ("3029", Simple, 192, 48, 81, 2),
        ("3070", Tile, 4, 0, 1, 4),
        ("2431", Tile, 16, 0, 7, 2),
        ("4150", Tile, 12, 0, 8, 4),
        ("6636", Tile, 24, 0, 11, 2),
        ("3068b", Tile, 16, 0, 5, 4),
        ("3069b", Tile, 8, 0, 3, 2),
        ("3070b", Tile, 4, 0, 1, 4),
        ("63864", Tile, 12, 0, 5, 2),
        ("4162", Tile, 32, 0, 15, 2),
        ("3794a", Jumper, 8, 1, 3, 2),
        ("87580", Jumper, 16, 1, 5, 4),
        ("2420", Corner, 12, 3, 5, 1),
        ("2357", Corner, 36, 3, 5, 1),
        // Base slab layer (8) + the two cells under the apex in the middle layer.
        ("15571", Slope, 10, 0, 3, 1),
        // 45° slopes: per 1x1 column of cells in x, 6 (back row) + 2 + 1 cells.
        ("3039", Slope, 36, 2, 5, 1),
        ("3040b", Slope, 18, 1, 3, 1),
        // 33°: 6 + 3 + 2 + 1 + 1 per column.
        ("3298", Slope, 52, 2, 8, 1),
        ("3660", Slope, 36, 4, 3, 1),
        ("3665", Slope, 18, 2, 1, 1),
        ("37352", Slope, 20, 0, 3, 1),
        ("4286", Slope, 26, 1, 4, 1),
        // 75°: 18 + 7 + 3 per column; 65°: 12 + 5 + 2.
        ("4460b", Slope, 56, 1, 3, 1),
        ("60481", Slope, 38, 1, 3, 1),
        ("85984", Slope, 12, 0, 3, 1),
        ("54200", Misc, 6, 0, 1, 1),
        // Base plate (4) + the two cells where the walls meet.
        ("6231", Misc, 6, 0, 1, 1),
        ("87087", Misc, 12, 1, 1, 1),
    ]
};

fn def(id: &str) -> &'static PartDef {
    brickgeom::part(id).unwrap_or_else(|e| panic!("{id}: {e}"))
}

/// The four cells around a connection point on layer `layer` (as `component::cells_around`).
fn cells_around(p: Lattice, layer: i32) -> [Lattice; 4] {
    [
        [p[0] - 1, layer, p[2] - 1],
        [p[0], layer, p[2] - 1],
        [p[0] - 1, layer, p[2]],
        [p[0], layer, p[2]],
    ]
}

fn occupied_around(d: &PartDef, p: Lattice, layer: i32) -> usize {
    let vox: HashSet<Lattice> = d.voxels.iter().copied().collect();
    cells_around(p, layer)
        .iter()
        .filter(|c| vox.contains(*c))
        .count()
}

#[test]
fn table_has_the_72_paper_parts() {
    let lib = library();
    let ids = lib.ids();
    assert_eq!(ids.len(), 72);
    assert_eq!(
        ids.iter().collect::<HashSet<_>>().len(),
        72,
        "ids are unique"
    );
    let expected: Vec<&str> = EXPECTED.iter().map(|e| e.0).collect();
    assert_eq!(ids, expected);
    for (cat, n) in [
        (Category::Simple, 45),
        (Category::Tile, 9),
        (Category::Jumper, 2),
        (Category::Corner, 2),
        (Category::Slope, 11),
        (Category::Misc, 3),
    ] {
        let got = lib.parts().iter().filter(|p| p.category == cat).count();
        assert_eq!(got, n, "{cat:?}");
    }
    for p in lib.parts() {
        assert!(
            !p.name.is_empty() && !p.name.starts_with('~'),
            "{}: {}",
            p.id,
            p.name
        );
    }
    assert_eq!(def("3001").name, "Brick  2 x  4");
    assert_eq!(def("3023").name, "Plate  1 x  2");
    assert_eq!(def("4073").name, "Plate  1 x  1 Round");
}

#[test]
fn counts_match_the_hand_worked_table() {
    for &(id, cat, voxels, studs, anti, sym) in EXPECTED {
        let d = def(id);
        assert_eq!(d.category, cat, "{id}");
        assert_eq!(d.voxels.len(), voxels, "{id}: voxels");
        assert_eq!(d.studs.len(), studs, "{id}: studs");
        assert_eq!(d.anti_studs.len(), anti, "{id}: anti-studs");
        assert_eq!(d.symmetry, sym, "{id}: symmetry");
        let side = if id == "87087" { 1 } else { 0 };
        assert_eq!(d.side_studs, side, "{id}: side studs");
    }
}

#[test]
fn brick_2x4_in_detail() {
    let d = def("3001");
    let xs: BTreeSet<i32> = d.voxels.iter().map(|v| v[0]).collect();
    let ys: BTreeSet<i32> = d.voxels.iter().map(|v| v[1]).collect();
    let zs: BTreeSet<i32> = d.voxels.iter().map(|v| v[2]).collect();
    assert_eq!(xs, (-4..4).collect());
    assert_eq!(ys, (-3..0).collect());
    assert_eq!(zs, (-2..2).collect());
    assert!(d.studs.contains(&[-3, 0, -1]) && d.studs.contains(&[3, 0, 1]));
    for tube in [[-2, -3, 0], [0, -3, 0], [2, -3, 0]] {
        assert!(d.anti_studs.contains(&tube));
    }
    // 1x4 brick: long along x, half positions between its anti-studs.
    let d = def("3010");
    assert!(d
        .voxels
        .iter()
        .all(|v| (-4..4).contains(&v[0]) && (-1..1).contains(&v[2])));
    assert_eq!(
        d.anti_studs.iter().filter(|a| a[0] % 2 == 0).count(),
        3,
        "3 half positions"
    );
}

#[test]
fn sets_are_unique_and_symmetry_is_exact() {
    for d in library().parts() {
        assert!(!d.voxels.is_empty(), "{}", d.id);
        for (what, v) in [
            ("voxels", &d.voxels),
            ("studs", &d.studs),
            ("anti-studs", &d.anti_studs),
        ] {
            let set: HashSet<_> = v.iter().collect();
            assert_eq!(set.len(), v.len(), "{}: duplicate {what}", d.id);
        }
        assert!([1, 2, 4].contains(&d.symmetry), "{}", d.id);
        let sorted = |v: Vec<Lattice>| v.into_iter().collect::<BTreeSet<_>>();
        let quant = |p: [f32; 3]| p.map(|c| (c * 64.0).round() as i64);
        let mesh_set: HashSet<[i64; 3]> = d.mesh.vertices.iter().map(|&v| quant(v)).collect();
        let invariant = (0..4u8)
            .filter(|&r| {
                let v = sorted(d.voxels.iter().map(|&c| rotate_cell(c, r)).collect());
                let s = sorted(d.studs.iter().map(|&p| rotate_point(p, r)).collect());
                let a = sorted(d.anti_studs.iter().map(|&p| rotate_point(p, r)).collect());
                let lattice_same = v == sorted(d.voxels.clone())
                    && s == sorted(d.studs.clone())
                    && a == sorted(d.anti_studs.clone());
                // The visual shape too (87087's side stud is in the mesh only).
                let mesh_same = d
                    .mesh
                    .vertices
                    .iter()
                    .all(|&p| mesh_set.contains(&quant(rotate_ldu(p, r))));
                lattice_same && mesh_same
            })
            .count();
        assert_eq!(invariant, d.symmetry as usize, "{}", d.id);
    }
}

#[test]
fn studs_stand_on_the_body() {
    for d in library().parts() {
        for &s in &d.studs {
            assert_eq!(
                occupied_around(d, s, s[1]),
                0,
                "{}: stud {s:?} is buried",
                d.id
            );
            let below = occupied_around(d, s, s[1] - 1);
            let expected = match d.id {
                // Round 2x2 parts: the stud's outer cell is a corner cell the circle only clips.
                "4032a" | "3941" => 3,
                // The cone's top layer is less than half full; the stud stands on the cone tip.
                "59900" => {
                    assert_eq!(occupied_around(d, s, s[1] - 2), 4, "{}", d.id);
                    0
                }
                _ => 4,
            };
            assert_eq!(below, expected, "{}: stud {s:?}", d.id);
        }
    }
}

#[test]
fn anti_studs_are_under_the_body() {
    for d in library().parts() {
        let bottom = d.voxels.iter().map(|v| v[1]).min().unwrap();
        for &a in &d.anti_studs {
            assert_eq!(a[1], bottom, "{}: anti-stud {a:?} not at the bottom", d.id);
            let above = occupied_around(d, a, a[1]);
            let expected = match d.id {
                // Round 2x2 parts: a grid position's outer cell is a corner cell.
                "4032a" | "3941" | "4150" if a[0] != 0 && a[2] != 0 => 3,
                _ => 4,
            };
            assert_eq!(above, expected, "{}: anti-stud {a:?}", d.id);
        }
    }
    // Inverted slopes: anti-studs only under the narrow bottom (the back row, z = 0).
    for id in ["3660", "3665"] {
        assert!(def(id).anti_studs.iter().all(|a| a[2] == 0), "{id}");
    }
}

#[test]
fn slopes_have_studs_only_on_their_flat_top_row() {
    for d in library()
        .parts()
        .iter()
        .filter(|p| p.category == Category::Slope)
    {
        if d.id == "3660" || d.id == "3665" {
            continue;
        }
        assert!(d.studs.iter().all(|s| s[1] == 0 && s[2] == 0), "{}", d.id);
    }
}

fn triangle_area(a: [f32; 3], b: [f32; 3], c: [f32; 3]) -> f32 {
    let u = [b[0] - a[0], b[1] - a[1], b[2] - a[2]];
    let v = [c[0] - a[0], c[1] - a[1], c[2] - a[2]];
    let n = [
        u[1] * v[2] - u[2] * v[1],
        u[2] * v[0] - u[0] * v[2],
        u[0] * v[1] - u[1] * v[0],
    ];
    0.5 * (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt()
}

#[test]
fn meshes_are_valid_and_fit_the_voxels() {
    for d in library().parts() {
        let m = &d.mesh;
        let n = m.vertices.len() as u32;
        assert!(!m.triangles.is_empty(), "{}", d.id);
        for t in &m.triangles {
            assert!(t.iter().all(|&i| i < n), "{}: index out of range", d.id);
            let [a, b, c] = t.map(|i| m.vertices[i as usize]);
            assert!(
                triangle_area(a, b, c) > 1e-4,
                "{}: degenerate triangle {t:?}",
                d.id
            );
        }
        let (lo, hi) = m.bounds().unwrap();
        let vlo = [0, 2].map(|a| d.voxels.iter().map(|v| v[a]).min().unwrap() as f32 * 10.0);
        let vhi = [0, 2].map(|a| (d.voxels.iter().map(|v| v[a]).max().unwrap() + 1) as f32 * 10.0);
        // 87087's side stud sticks out 4 LDU on +z (LDraw's -z).
        let side = if d.side_studs > 0 { 4.0 } else { 0.0 };
        assert!(
            (lo[0] - vlo[0]).abs() <= 1.0 && (hi[0] - vhi[0]).abs() <= 1.0,
            "{}: x {lo:?} {hi:?}",
            d.id
        );
        assert!(
            (lo[2] - vlo[1]).abs() <= 1.0 && (hi[2] - side - vhi[1]).abs() <= 1.0,
            "{}: z {lo:?} {hi:?}",
            d.id
        );
        let vbottom = d.voxels.iter().map(|v| v[1]).min().unwrap() as f32 * 8.0;
        let vtop = (d.voxels.iter().map(|v| v[1]).max().unwrap() + 1) as f32 * 8.0;
        assert!(
            (lo[1] - vbottom).abs() <= 1.0,
            "{}: bottom {} vs {vbottom}",
            d.id,
            lo[1]
        );
        let top_face = d.keypoint[1];
        assert!(vtop <= top_face, "{}: voxels above the top face", d.id);
        let stud_top = if d.studs.is_empty() { 0.0 } else { 4.0 };
        assert!(
            (hi[1] - (top_face + stud_top)).abs() <= 1.0,
            "{}: top {} vs face {top_face}",
            d.id,
            hi[1]
        );
        assert_eq!([d.keypoint[0], d.keypoint[2]], [0.0, 0.0], "{}", d.id);
    }
}

/// Outward winding: the signed volume of the mesh (closed solids plus open-bottom studs) is
/// positive and of the size of the body.
#[test]
fn meshes_wind_outward() {
    for d in library().parts() {
        let v = &d.mesh.vertices;
        let vol: f32 = d
            .mesh
            .triangles
            .iter()
            .map(|t| {
                let [a, b, c] = t.map(|i| v[i as usize]);
                (a[0] * (b[1] * c[2] - b[2] * c[1]) - a[1] * (b[0] * c[2] - b[2] * c[0])
                    + a[2] * (b[0] * c[1] - b[1] * c[0]))
                    / 6.0
            })
            .sum();
        let voxel_vol = d.voxels.len() as f32 * 800.0;
        let stud_vol =
            (d.studs.len() + d.side_studs as usize) as f32 * std::f32::consts::PI * 36.0 * 4.0;
        assert!(
            vol > 0.6 * voxel_vol && vol < 1.6 * voxel_vol + stud_vol,
            "{}: signed volume {vol} vs voxels {voxel_vol}",
            d.id
        );
    }
}

#[test]
fn aliases_resolve_to_library_parts() {
    let lib = library();
    for (alias, target) in [
        ("3023b", "3023"),
        ("6141", "4073"),
        ("3070a", "3070"),
        ("3660a", "3660"),
        ("3665a", "3665"),
        ("60481a", "60481"),
        ("3794b", "3794a"),
        ("4032b", "4032a"),
        ("4589", "59900"),
        ("3069bps1", "3069b"),
    ] {
        assert_eq!(lib.resolve(alias), Some(target), "{alias}");
    }
    assert_eq!(lib.resolve("parts\\6141.DAT"), Some("4073"));
    assert_eq!(
        lib.resolve("3070b.dat"),
        Some("3070b"),
        "3070b is its own part"
    );
    assert_eq!(lib.resolve("3070"), Some("3070"));
    assert_eq!(
        lib.resolve("3065"),
        Some("3004"),
        "1x2 brick without bottom tube"
    );
    // Different parts with the same footprint are not aliases (grille tile, masonry brick).
    assert_eq!(lib.resolve("2412b"), None);
    assert_eq!(lib.resolve("98283"), None);
    assert_eq!(lib.resolve("3001old"), None);
}

/// `silhouette_iou` draws only the faces turned towards the camera: that leaves every part's
/// silhouette and nearest depth as the renderer draws them (all faces) only if the meshes are
/// closed and wound outwards. Every part, every yaw, views from above, the side and below.
#[test]
fn every_part_keeps_its_silhouette_with_only_the_faces_turned_to_the_camera() {
    use brickgeom::camera::Camera;
    use brickgeom::raster::{render, silhouette_iou, MaskTarget, RenderItem, RenderOptions};
    use brickgeom::Pose;

    let w = 96u32;
    let n = (w * w) as usize;
    for p in library().parts() {
        for (elevation, azimuth) in [(30.0, 225.0), (20.0, 45.0), (0.0, 130.0), (-35.0, 300.0)] {
            for yaw in 0..4u8 {
                let pose = Pose::new(yaw, [0, 0, 0]);
                let cam = Camera::new(elevation, azimuth, 0.0, 0.012, [0.0, 0.0]).unwrap();
                let item = RenderItem {
                    pose,
                    ..RenderItem::new(&p.mesh, [200, 200, 200])
                };
                let drawn = render(&[item], &cam, &RenderOptions::new(w, w)).unwrap();
                let mask: Vec<bool> = drawn.ids.iter().map(|&i| i == 0).collect();
                let area = mask.iter().filter(|&&m| m).count();
                assert!(area > 20, "{} too small to check", p.id);
                // what stands just behind the part's drawn surface: the part shows in front of
                // it only with its near faces
                let behind: Vec<f32> = drawn.depth.iter().map(|&d| d + 0.5).collect();
                assert_eq!(behind.len(), n);
                let target = MaskTarget::new(w, w, behind, mask).unwrap();
                let (iou, visible) = silhouette_iou(&[(&p.mesh, pose)], &cam, &target).unwrap();
                // a pixel or two where faces meet is rasterization, a face missing is hundreds
                assert!(
                    iou >= 0.99 && (visible as usize).abs_diff(area) <= 2,
                    "{} yaw {yaw} view ({elevation}, {azimuth}): IoU {iou}, {visible} of {area} px",
                    p.id
                );
            }
        }
    }
}
