//! Every real model in `../shared/real/models` parses, flattens, and round-trips through the
//! writer. Skipped (with a message) when the folder is absent.

use std::path::PathBuf;

use brickgeom::ldraw::{lattice_pose, parse_ldraw, read_ldraw, write_ldraw_string};

fn real_models() -> Vec<PathBuf> {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../shared/real/models");
    let Ok(entries) = std::fs::read_dir(&dir) else {
        eprintln!("skip: no real models at {}", dir.display());
        return Vec::new();
    };
    let mut files: Vec<PathBuf> = entries
        .flatten()
        .map(|e| e.path())
        .filter(|p| {
            p.extension()
                .is_some_and(|e| e.eq_ignore_ascii_case("mpd") || e.eq_ignore_ascii_case("ldr"))
        })
        .collect();
    files.sort();
    files
}

#[test]
fn real_models_parse_and_flatten() {
    for path in real_models() {
        let file = read_ldraw(&path).unwrap_or_else(|e| panic!("{e}"));
        let parts = file.flatten();
        let main = &file.models[0];
        let (mut off, mut non_yaw) = (0, 0);
        for p in &parts {
            let lp = lattice_pose(p.position, p.matrix);
            off += usize::from(lp.off_lattice);
            non_yaw += usize::from(lp.non_yaw);
        }
        // The same, for part references in their own model's frame.
        let (mut local_off, mut local_non_yaw) = (0, 0);
        for r in file.models.iter().flat_map(|m| m.steps.iter().flatten()) {
            if !r.is_submodel {
                let lp = lattice_pose(r.position, r.matrix);
                local_off += usize::from(lp.off_lattice);
                local_non_yaw += usize::from(lp.non_yaw);
            }
        }
        let all_steps: usize = file.models.iter().map(|m| m.steps.len()).sum();
        println!(
            "{:<48} steps {:>3} main/{:>3} all, submodels {:>2}, embedded {}, parts {:>3}; \
             off-lattice/non-yaw world {:>3}/{:>3}, local {:>3}/{:>3}",
            file.name,
            main.steps.len(),
            all_steps,
            file.models.len() - 1,
            file.embedded_parts.len(),
            parts.len(),
            off,
            non_yaw,
            local_off,
            local_non_yaw
        );
        assert!(!parts.is_empty());
        assert!(parts.iter().all(|p| p.step < main.steps.len()));
    }
}

#[test]
fn real_models_round_trip_through_the_writer() {
    for path in real_models() {
        let bytes = std::fs::read(&path).unwrap();
        let name = path.file_name().unwrap().to_string_lossy().to_string();
        let first = parse_ldraw(&bytes, &name).unwrap();
        let text = write_ldraw_string(&first);
        let second = parse_ldraw(text.as_bytes(), &name).unwrap_or_else(|e| panic!("{name}: {e}"));
        assert_eq!(first, second, "{name}");
        assert_eq!(first.flatten().len(), second.flatten().len());
        // And the writer is a fixed point after one pass.
        assert_eq!(write_ldraw_string(&second), text, "{name}");
    }
}

/// Every part the real models place (outside the parts they embed) loads from the shared
/// LDraw library; unusual references (subfolders, primitives, odd case) are listed.
#[test]
fn real_model_parts_have_library_geometry() {
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../shared/ldraw");
    let Ok(mut loader) = brickgeom::ldraw::PartLoader::new(&root) else {
        eprintln!("skip: no LDraw library at {}", root.display());
        return;
    };
    let mut failures = Vec::new();
    let mut distinct = std::collections::BTreeSet::new();
    for path in real_models() {
        let file = read_ldraw(&path).unwrap();
        let embedded: Vec<String> = file
            .embedded_parts
            .iter()
            .map(|p| brickgeom::ldraw::normalise_name(&p.name))
            .collect();
        for part in file.flatten() {
            if embedded.contains(&part.name) || !distinct.insert(part.name.clone()) {
                continue;
            }
            if part.name.contains('/') || !part.name.ends_with(".dat") {
                println!("unusual reference in {}: {}", file.name, part.name);
            }
            if let Err(e) = loader.load(&part.name) {
                failures.push(format!("{}: {e}", file.name));
            }
        }
    }
    println!("{} distinct parts load", distinct.len());
    assert!(failures.is_empty(), "{failures:#?}");
}
