//! Part geometry from the shared LDraw library (`../shared/ldraw`); skipped when it is absent.

use std::path::PathBuf;

use brickgeom::ldraw::{load_part_geometry, PartGeometry, PartLoader};
use brickgeom::BrickGeomError;

fn ldraw_root() -> Option<PathBuf> {
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../shared/ldraw");
    if root.join("parts").is_dir() {
        Some(root)
    } else {
        eprintln!("skip: no LDraw library at {}", root.display());
        None
    }
}

fn bounds(g: &PartGeometry) -> ([f32; 3], [f32; 3]) {
    g.mesh.bounds().expect("non-empty mesh")
}

fn assert_close(a: [f32; 3], b: [f32; 3]) {
    for i in 0..3 {
        assert!((a[i] - b[i]).abs() < 1e-3, "{a:?} != {b:?}");
    }
}

#[test]
fn brick_2x4() {
    let Some(root) = ldraw_root() else { return };
    let g = load_part_geometry(&root, "3001").unwrap();
    assert_eq!(g.stud_count, 8);
    let (lo, hi) = bounds(&g);
    assert_close(lo, [-40.0, -24.0, -20.0]);
    assert_close(hi, [40.0, 4.0, 20.0]);
    for p in &g.stud_positions {
        assert_eq!(p[1], 0.0, "studs sit on the top face (y = 0)");
        assert_eq!((p[0] + 30.0) % 20.0, 0.0);
        assert!(p[2] == -10.0 || p[2] == 10.0);
    }
    assert!(g.mesh.triangles.len() > 500);
    // Same part through other spellings.
    let same = load_part_geometry(&root, "PARTS\\3001.DAT").unwrap();
    assert_eq!(same.mesh, g.mesh);
}

#[test]
fn round_brick_and_side_stud() {
    let Some(root) = ldraw_root() else { return };
    let round = load_part_geometry(&root, "3062b").unwrap();
    assert_eq!(round.stud_count, 1);
    let (lo, hi) = bounds(&round);
    assert_close(lo, [-10.0, -24.0, -10.0]);
    assert_close(hi, [10.0, 4.0, 10.0]);
    assert_eq!(round.stud_positions, vec![[0.0, 0.0, 0.0]]);

    // 87087: one top stud; the side stud (pointing LDraw's -z, the lattice's +z) is not a top
    // stud.
    let side = load_part_geometry(&root, "87087").unwrap();
    assert_eq!(side.stud_count, 1);
    let (lo, hi) = bounds(&side);
    assert_close(lo, [-10.0, -24.0, -10.0]);
    assert_close(hi, [10.0, 4.0, 14.0]);
}

#[test]
fn moved_part_loads_through_its_reference() {
    let Some(root) = ldraw_root() else { return };
    let moved = load_part_geometry(&root, "3023").unwrap();
    let target = load_part_geometry(&root, "3023b").unwrap();
    assert_eq!(moved.mesh, target.mesh);
    assert_eq!(moved.stud_count, 2);
    let (lo, hi) = bounds(&moved);
    assert_close(lo, [-20.0, -8.0, -10.0]);
    assert_close(hi, [20.0, 4.0, 10.0]);
}

#[test]
fn missing_part_is_a_missing_reference() {
    let Some(root) = ldraw_root() else { return };
    let err = load_part_geometry(&root, "no-such-part").unwrap_err();
    assert!(
        matches!(err, BrickGeomError::MissingReference { .. }),
        "{err}"
    );
}

/// The 72 primitive types of DESIGN §3 and their top studs (hollow studs count, side studs and
/// tile tops do not).
#[test]
fn library_parts_load_with_expected_studs() {
    let Some(root) = ldraw_root() else { return };
    let expected: &[(&str, usize)] = &[
        ("3024", 1),
        ("3005", 1),
        ("3023", 2),
        ("3004", 2),
        ("3623", 3),
        ("3622", 3),
        ("3010", 4),
        ("3666", 6),
        ("3009", 6),
        ("3460", 8),
        ("3008", 8),
        ("3022", 4),
        ("3003", 4),
        ("3021", 6),
        ("3020", 8),
        ("3001", 8),
        ("3795", 12),
        ("2456", 12),
        ("3034", 16),
        ("3007", 16),
        ("3036", 48),
        ("41539", 64),
        ("3958", 36),
        ("3033", 60),
        ("3002", 6),
        ("2445", 24),
        ("3030", 40),
        ("3031", 16),
        ("3032", 24),
        ("3035", 32),
        ("3710", 4),
        ("3832", 20),
        ("4073", 1),
        ("4477", 10),
        ("6112", 12),
        ("3062b", 1),
        ("3245a", 2),
        ("4032a", 4),
        ("60479", 12),
        ("4282", 32),
        ("22886", 2),
        ("3941", 4),
        ("2877", 2),
        ("59900", 1),
        ("3029", 48),
        ("3070", 0),
        ("2431", 0),
        ("4150", 0),
        ("6636", 0),
        ("3068b", 0),
        ("3069b", 0),
        ("3070b", 0),
        ("63864", 0),
        ("4162", 0),
        ("3794a", 1),
        ("87580", 1),
        ("2420", 3),
        ("2357", 3),
        ("15571", 0),
        ("3039", 2),
        ("3040b", 1),
        ("3298", 2),
        ("3660", 4),
        ("3665", 2),
        ("37352", 0),
        ("4286", 1),
        ("4460b", 1),
        ("60481", 1),
        ("85984", 0),
        ("54200", 0),
        ("6231", 0),
        ("87087", 1),
    ];
    assert_eq!(expected.len(), 72);
    let mut loader = PartLoader::new(&root).unwrap();
    let mut wrong = Vec::new();
    for &(id, studs) in expected {
        let g = loader.load(id).unwrap_or_else(|e| panic!("{id}: {e}"));
        let (lo, hi) = bounds(&g);
        println!(
            "{id:>6}: {:>3} studs, {:>6} tris, {lo:?}..{hi:?}",
            g.stud_count,
            g.mesh.triangles.len()
        );
        if g.stud_count != studs {
            wrong.push(format!("{id}: {} studs, expected {studs}", g.stud_count));
        }
    }
    assert!(wrong.is_empty(), "{wrong:?}");
}

/// BFC-certified parts come out with outward (counter-clockwise, y-up frame) triangles: the
/// signed volume of a closed-ish shell is positive and close to the solid's volume.
#[test]
fn winding_is_outward() {
    let Some(root) = ldraw_root() else { return };
    let mut loader = PartLoader::new(&root).unwrap();
    for id in ["3001", "3003", "3024", "3062b", "3039", "87087", "3070b"] {
        let g = loader.load(id).unwrap();
        let v = &g.mesh.vertices;
        let vol: f64 = g
            .mesh
            .triangles
            .iter()
            .map(|t| {
                let [a, b, c] = t.map(|i| v[i as usize].map(f64::from));
                (a[0] * (b[1] * c[2] - b[2] * c[1]) - a[1] * (b[0] * c[2] - b[2] * c[0])
                    + a[2] * (b[0] * c[1] - b[1] * c[0]))
                    / 6.0
            })
            .sum();
        println!("{id}: signed volume {vol:.1} LDU^3");
        assert!(vol > 0.0, "{id}: signed volume {vol}");
    }
}

/// Every part in the shared library loads (no missing subfiles, no parse errors).
#[test]
fn every_library_file_loads() {
    let Some(root) = ldraw_root() else { return };
    let mut loader = PartLoader::new(&root).unwrap();
    let mut n = 0;
    for entry in std::fs::read_dir(root.join("parts")).unwrap().flatten() {
        let name = entry.file_name().to_string_lossy().to_string();
        if name.ends_with(".dat") {
            loader.load(&name).unwrap_or_else(|e| panic!("{name}: {e}"));
            n += 1;
        }
    }
    println!("{n} parts loaded");
    assert!(n > 100);
}

/// A throw-away library folder with the given `parts/` files.
fn temp_library(tag: &str, files: &[(&str, &str)]) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("brickgeom-{tag}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(dir.join("parts/s")).unwrap();
    std::fs::create_dir_all(dir.join("p")).unwrap();
    for (name, text) in files {
        std::fs::write(dir.join(name), text).unwrap();
    }
    dir
}

#[test]
fn errors_name_the_file_and_line() {
    let dir = temp_library(
        "geom-errors",
        &[
            (
                "parts/cyc.dat",
                "0 a\n1 16 0 0 0 1 0 0 0 1 0 0 0 1 S\\Cyc2.DAT\n",
            ),
            ("parts/s/cyc2.dat", "1 16 0 0 0 1 0 0 0 1 0 0 0 1 cyc.dat\n"),
            ("parts/bad.dat", "0 x\n\n3 16 0 0 0 1 1 1 nan 0 0\n"),
            ("parts/short.dat", "4 16 0 0 0 1 1 1 2 2 2\n"),
            (
                "parts/miss.dat",
                "0 x\n1 16 0 0 0 1 0 0 0 1 0 0 0 1 gone.dat\n",
            ),
            (
                "parts/Tri.DAT",
                "0 BFC CERTIFY CW\n3 16 0 0 0 1 0 0 0 0 1\n",
            ),
        ],
    );
    let err = load_part_geometry(&dir, "cyc").unwrap_err();
    assert_eq!(
        err,
        BrickGeomError::CyclicReference {
            file: "cyc.dat".into(),
            chain: "cyc.dat -> s/cyc2.dat -> cyc.dat".into()
        }
    );
    let err = load_part_geometry(&dir, "bad").unwrap_err();
    assert!(
        matches!(err, BrickGeomError::Parse { line: 3, .. }),
        "{err}"
    );
    let err = load_part_geometry(&dir, "short").unwrap_err();
    assert!(
        matches!(err, BrickGeomError::Parse { line: 1, .. }),
        "{err}"
    );
    let err = load_part_geometry(&dir, "miss").unwrap_err();
    assert_eq!(
        err,
        BrickGeomError::MissingReference {
            file: "miss.dat".into(),
            line: 2,
            name: "gone.dat".into()
        }
    );
    // Case-insensitive file name; CW winding is flipped to CCW, then mirrored by y -> -y.
    let tri = load_part_geometry(&dir, "tri").unwrap();
    assert_eq!(tri.mesh.triangles.len(), 1);
    assert_eq!(tri.stud_count, 0);
    let _ = std::fs::remove_dir_all(&dir);
}
