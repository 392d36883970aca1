//! Deeply nested submodels (model k references model k + 1): reading refuses nesting past
//! `MAX_NESTING` with an error naming the file and the depth, and the walks over a model tree
//! (flatten, the lattice resolution, step checks) survive any depth of a hand-built file
//! without recursion. Before the bound, a 20,000-deep file overflowed the stack.

use brickgeom::ldraw::{parse_ldraw, LdrawFile, LdrawModel, LdrawRef, MAX_NESTING};
use brickgeom::realmodel::{check_model_steps, LatticeFile};
use brickgeom::BrickGeomError;

const IDENTITY: [[f64; 3]; 3] = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];

/// An .mpd of `models` models nested `models - 1` levels deep; the last holds one 3001.
fn chain_text(models: usize) -> String {
    let mut s = String::new();
    for k in 0..models {
        s += &format!("0 FILE m{k}.ldr\n");
        if k + 1 < models {
            s += &format!("1 16 0 0 0 1 0 0 0 1 0 0 0 1 m{}.ldr\n", k + 1);
        } else {
            s += "1 4 0 0 0 1 0 0 0 1 0 0 0 1 3001.dat\n";
        }
    }
    s
}

/// The same chain built in memory, bypassing the reader and its checks.
fn chain_file(models: usize) -> LdrawFile {
    let reference = |name: String, colour: i32, is_submodel: bool| LdrawRef {
        line: 0,
        colour,
        position: [0.0; 3],
        matrix: IDENTITY,
        name,
        is_submodel,
    };
    LdrawFile {
        name: "deep.mpd".into(),
        models: (0..models)
            .map(|k| LdrawModel {
                name: format!("m{k}.ldr"),
                title: String::new(),
                steps: vec![vec![if k + 1 < models {
                    reference(format!("m{}.ldr", k + 1), 16, true)
                } else {
                    reference("3001.dat".into(), 4, false)
                }]],
            })
            .collect(),
        embedded_parts: Vec::new(),
    }
}

fn assert_too_deep(models: usize) {
    let err = parse_ldraw(chain_text(models).as_bytes(), "deep.mpd").unwrap_err();
    let BrickGeomError::Parse { file, line, .. } = &err else {
        panic!("expected a parse error, got {err:?}");
    };
    assert_eq!(file, "deep.mpd");
    // the reference placing m65.ldr is the second line of m64.ldr's block: 2 * 64 + 2
    assert_eq!(*line, 2 * (MAX_NESTING + 1));
    let msg = err.to_string();
    assert_eq!(
        msg,
        format!(
            "deep.mpd:{line}: submodels nested deeper than {MAX_NESTING} levels (model 'm{}.ldr' \
             is {} levels below 'm0.ldr')",
            MAX_NESTING + 1,
            MAX_NESTING + 1
        )
    );
}

#[test]
fn nesting_20000_deep_is_a_clean_error() {
    assert_too_deep(20_000);
}

#[test]
fn nesting_2000_deep_is_a_clean_error() {
    assert_too_deep(2_000);
}

#[test]
fn nesting_one_past_the_limit_is_an_error() {
    assert_too_deep(MAX_NESTING + 2);
}

#[test]
fn nesting_at_the_limit_reads_flattens_and_checks() {
    // MAX_NESTING + 1 models: m0 and MAX_NESTING levels of submodels below it.
    let file = parse_ldraw(chain_text(MAX_NESTING + 1).as_bytes(), "deep.mpd").unwrap();
    assert_eq!(file.models.len(), MAX_NESTING + 1);
    let parts = file.flatten();
    assert_eq!(parts.len(), 1);
    assert_eq!(parts[0].name, "3001.dat");
    assert_eq!(parts[0].colour, 4);
    assert_eq!(parts[0].path.len(), MAX_NESTING);
    let lf = LatticeFile::new(&file);
    assert!(lf.placeable.iter().all(|&p| p));
    let checks = check_model_steps(&lf, 0).unwrap();
    assert_eq!(checks.len(), 1);
}

#[test]
fn deep_hand_built_files_do_not_overflow_the_stack() {
    // Files built in memory (as the Python binding does from dicts) skip the reader's bound;
    // every walk must still be iterative. Run on a small stack to make a regression loud.
    let worker = std::thread::Builder::new()
        .stack_size(256 * 1024)
        .spawn(|| {
            let file = chain_file(20_000);
            let parts = file.flatten();
            assert_eq!(parts.len(), 1);
            assert_eq!(parts[0].path.len(), 19_999);
            let lf = LatticeFile::new(&file);
            assert_eq!(lf.models.len(), 20_000);
            assert!(lf.placeable[0]);
            let checks = check_model_steps(&lf, 0).unwrap();
            assert_eq!(checks.len(), 1);
        })
        .unwrap();
    worker.join().unwrap();
}

#[test]
fn a_cycle_in_a_hand_built_file_does_not_recurse() {
    let mut file = chain_file(3);
    file.models[2].steps[0][0] = LdrawRef {
        line: 0,
        colour: 16,
        position: [0.0; 3],
        matrix: IDENTITY,
        name: "m0.ldr".into(),
        is_submodel: true,
    };
    assert!(file.flatten().is_empty());
    let lf = LatticeFile::new(&file);
    assert!(lf.placeable.iter().all(|&p| !p));
}
