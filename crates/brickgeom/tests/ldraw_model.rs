//! The LDraw model reader, pose conversion, flattening and writer.

use brickgeom::lattice::yaw_matrix;
use brickgeom::ldraw::{
    lattice_pose, ldraw_placement, parse_ldraw, read_ldraw, write_ldraw, write_ldraw_string,
    LdrawFile, LdrawModel, LdrawRef,
};
use brickgeom::{BrickGeomError, Pose};
use proptest::prelude::*;

const I: &str = "1 0 0 0 1 0 0 0 1";

fn parse(text: &str) -> Result<LdrawFile, BrickGeomError> {
    parse_ldraw(text.as_bytes(), "test.mpd")
}

fn parse_err_line(text: &str) -> usize {
    match parse(text) {
        Err(BrickGeomError::Parse { line, file, .. }) => {
            assert_eq!(file, "test.mpd");
            line
        }
        other => panic!("expected a parse error, got {other:?}"),
    }
}

#[test]
fn plain_ldr_steps_and_names() {
    let text = format!(
        "0 My house\r\n0 Name: house.ldr\r\n0 Author: me\r\n\
         1 4 10 -24 0 {I} 3001.dat\r\n0 STEP\r\n0 STEP\r\n\
         1 16 0 0 0 {I} Parts\\S\\3001S01.DAT\r\n2 24 0 0 0 1 1 1\r\n0 ROTSTEP 0 45 0 ABS\r\n\
         1 0x2FF0000 0 -8 0 {I} my  odd part.dat\r\n"
    );
    let f = parse_ldraw(text.as_bytes(), "dir/house.ldr").unwrap();
    assert_eq!(f.name, "house.ldr");
    assert_eq!(f.models.len(), 1);
    let m = &f.models[0];
    assert_eq!(m.name, "house.ldr");
    assert_eq!(m.title, "My house");
    // The empty step between the two STEP lines is dropped; the trailing step counts.
    assert_eq!(m.steps.len(), 3);
    let r = &m.steps[0][0];
    assert_eq!((r.line, r.colour, r.position), (4, 4, [10.0, -24.0, 0.0]));
    assert_eq!(r.name, "3001.dat");
    assert_eq!(m.steps[1][0].name, "parts/s/3001s01.dat");
    assert_eq!(m.steps[2][0].name, "my  odd part.dat");
    assert_eq!(m.steps[2][0].colour, 0x2FF0000);
    assert!(!r.is_submodel);
}

#[test]
fn mpd_blocks_submodels_and_embedded_parts() {
    let text = format!(
        "0 FILE Main.ldr\n0 Main model\n1 1 0 0 0 {I} SUB car.LDR\n1 2 0 -24 0 {I} custom.dat\n\
         0 STEP\n0 NOFILE\n0 between blocks\n\
         0 FILE sub car.ldr\n1 16 20 0 0 {I} 3001.dat\n0 NOFILE\n\
         0 FILE custom.dat\n0 Custom part\n0 !LDRAW_ORG Unofficial_Part\n3 16 0 0 0 1 0 0 0 0 1\n\n"
    );
    let f = parse(&text).unwrap();
    assert_eq!(f.models.len(), 2);
    assert_eq!(f.models[0].title, "Main model");
    assert_eq!(f.models[1].name, "sub car.ldr");
    let refs = &f.models[0].steps[0];
    assert!(refs[0].is_submodel);
    assert_eq!(refs[0].name, "sub car.ldr");
    assert!(!refs[1].is_submodel, "embedded parts are parts");
    assert_eq!(f.embedded_parts.len(), 1);
    assert_eq!(f.embedded_parts[0].name, "custom.dat");
    assert_eq!(
        f.embedded_parts[0].text,
        "0 Custom part\n0 !LDRAW_ORG Unofficial_Part\n3 16 0 0 0 1 0 0 0 0 1"
    );
    assert!(f.model("SUB CAR.LDR").is_some());

    let flat = f.flatten();
    assert_eq!(flat.len(), 2);
    // 3001 inside the submodel: colour 16 inherits 1, position composed, path recorded.
    assert_eq!(flat[0].name, "3001.dat");
    assert_eq!(flat[0].colour, 1);
    assert_eq!(flat[0].position, [20.0, 0.0, 0.0]);
    assert_eq!(flat[0].path, vec!["sub car.ldr".to_string()]);
    assert_eq!(flat[1].name, "custom.dat");
    assert!(flat[1].path.is_empty());
}

#[test]
fn flatten_composes_rotations_and_steps() {
    // Submodel rotated a quarter turn and moved; the part inside sits at x = 20.
    let m = yaw_matrix(1).map(|r| r.map(f64::from));
    let rot: Vec<String> = m.iter().flatten().map(|v| format!("{v}")).collect();
    let text = format!(
        "0 FILE a.ldr\n1 4 0 0 0 {I} 3001.dat\n0 STEP\n1 16 100 -8 0 {} b.ldr\n0 NOFILE\n\
         0 FILE b.ldr\n1 16 20 0 0 {I} 3003.dat\n0 STEP\n1 24 0 0 0 {I} 3005.dat\n0 NOFILE\n",
        rot.join(" ")
    );
    let flat = parse(&text).unwrap().flatten();
    assert_eq!(flat.len(), 3);
    assert_eq!(flat[0].step, 0);
    assert_eq!(flat[1].step, 1);
    assert_eq!(flat[2].step, 1);
    assert_eq!(flat[1].colour, 16, "nothing above sets a colour");
    // yaw 1 maps (x, y, z) to (z, y, -x): (20, 0, 0) -> (0, 0, -20), then + (100, -8, 0).
    assert_eq!(flat[1].position, [100.0, -8.0, -20.0]);
    // The lattice is LDraw turned half a turn about x: z negated, and LDraw's quarter turn
    // about y is the lattice's quarter turn the other way (yaw 3).
    let lp = lattice_pose(flat[1].position, flat[1].matrix);
    assert_eq!(lp.pose, Pose::new(3, [10, 1, 2]));
    assert!(!lp.off_lattice && !lp.non_yaw);
}

#[test]
fn reference_errors() {
    let missing = parse_ldraw(format!("1 16 0 0 0 {I} other.ldr\n").as_bytes(), "a.ldr");
    assert_eq!(
        missing.unwrap_err(),
        BrickGeomError::MissingReference {
            file: "a.ldr".into(),
            line: 1,
            name: "other.ldr".into()
        }
    );
    let cyclic = format!(
        "0 FILE a.ldr\n1 16 0 0 0 {I} b.ldr\n0 FILE b.ldr\n1 16 0 0 0 {I} c.ldr\n\
         0 FILE c.ldr\n1 16 0 0 0 {I} B.LDR\n"
    );
    assert_eq!(
        parse(&cyclic).unwrap_err(),
        BrickGeomError::CyclicReference {
            file: "test.mpd".into(),
            chain: "b.ldr -> c.ldr -> b.ldr".into()
        }
    );
    let self_ref = format!("0 FILE a.ldr\n1 16 0 0 0 {I} a.ldr\n");
    assert!(matches!(
        parse(&self_ref),
        Err(BrickGeomError::CyclicReference { .. })
    ));
}

#[test]
fn bad_input_names_the_line() {
    assert_eq!(parse_err_line(""), 1);
    assert_eq!(parse_err_line("  \n\n"), 1);
    assert_eq!(parse_err_line("0 hi\n1 16 0\0 0"), 1);
    assert_eq!(parse_err_line("0 x\n1 16 0 0 0 1 0 0 0 1 0 0 0 1\n"), 2);
    assert_eq!(
        parse_err_line(&format!("0 x\n\n1 16 0 zero 0 {I} a.dat\n")),
        3
    );
    assert_eq!(parse_err_line(&format!("1 16 NaN 0 0 {I} a.dat\n")), 1);
    assert_eq!(parse_err_line(&format!("1 16 inf 0 0 {I} a.dat\n")), 1);
    assert_eq!(parse_err_line(&format!("1 16 2e6 0 0 {I} a.dat\n")), 1);
    assert_eq!(parse_err_line(&format!("1 red 0 0 0 {I} a.dat\n")), 1);
    assert_eq!(parse_err_line("1 16 0 0 0 1 0 0 0 0 0 0 0 1 a.dat\n"), 1);
    assert_eq!(parse_err_line(&format!("1 16 0 0 0 {I} a.dat\nhello\n")), 2);
    assert_eq!(parse_err_line("0 only comments\n0 STEP\n"), 1);
    assert_eq!(
        parse_err_line(&format!("1 16 0 0 0 {I} a.dat\n0 FILE x.ldr\n")),
        1
    );
    let dup = format!("0 FILE a.ldr\n1 16 0 0 0 {I} a.dat\n0 FILE A.LDR\n");
    assert_eq!(parse_err_line(&dup), 3);
    // Latin-1 comments are fine.
    assert!(parse_ldraw(
        format!("0 caf\u{e9}\n1 16 0 0 0 {I} a.dat").as_bytes(),
        "x.ldr"
    )
    .is_ok());
    assert!(parse_ldraw(
        &[
            b"0 caf\xe9\n".as_slice(),
            format!("1 16 0 0 0 {I} a.dat").as_bytes()
        ]
        .concat(),
        "x.ldr"
    )
    .is_ok());
}

#[test]
fn exponential_expansion_is_rejected() {
    let mut text = String::new();
    for i in 0..30 {
        text += &format!(
            "0 FILE m{i}.ldr\n1 16 0 0 0 {I} m{}.ldr\n1 16 0 0 0 {I} m{}.ldr\n",
            i + 1,
            i + 1
        );
    }
    text += &format!("0 FILE m30.ldr\n1 16 0 0 0 {I} 3001.dat\n");
    assert!(matches!(parse(&text), Err(BrickGeomError::Parse { .. })));
}

#[test]
fn lattice_pose_conversion() {
    for yaw in 0..4u8 {
        for t in [[0, 0, 0], [3, -2, 5], [-7, 12, 1]] {
            let pose = Pose::new(yaw, t);
            let (p, m) = ldraw_placement(pose);
            let back = lattice_pose(p, m);
            assert_eq!(back.pose, pose);
            assert!(!back.off_lattice && !back.non_yaw);
        }
    }
    // y down in LDraw: a brick on a 2x4 brick (24 LDU up) is at y = -24 -> lattice y = 3.
    let lp = lattice_pose(
        [20.0, -24.0, -10.0],
        yaw_matrix(0).map(|r| r.map(f64::from)),
    );
    assert_eq!(lp.pose.t, [2, 3, 1], "LDraw z = -10 is lattice z = +1");
    let off = lattice_pose([1.0, 2.5, 0.04], yaw_matrix(0).map(|r| r.map(f64::from)));
    assert!(off.off_lattice);
    assert_eq!(off.pose.t, [0, 0, 0]);
    let c = std::f64::consts::FRAC_1_SQRT_2;
    let tilted = lattice_pose([0.0; 3], [[c, 0.0, -c], [0.0, 1.0, 0.0], [c, 0.0, c]]);
    assert!(tilted.non_yaw && !tilted.off_lattice);
    assert_eq!(tilted.pose.yaw, 0);
    let nan = lattice_pose(
        [f64::NAN, 0.0, 1e300],
        yaw_matrix(0).map(|r| r.map(f64::from)),
    );
    assert!(nan.off_lattice);
}

#[test]
fn writer_layouts() {
    let r = LdrawRef {
        line: 0,
        colour: 4,
        position: [10.0, -24.0, 0.5],
        matrix: yaw_matrix(1).map(|r| r.map(f64::from)),
        name: "s/3001s01.dat".into(),
        is_submodel: false,
    };
    let single = LdrawFile {
        name: "plan.ldr".into(),
        models: vec![LdrawModel {
            name: "plan.ldr".into(),
            title: "A plan".into(),
            steps: vec![vec![r.clone()], vec![r.clone(), r.clone()]],
        }],
        embedded_parts: vec![],
    };
    let text = write_ldraw_string(&single);
    assert_eq!(
        text.lines().take(4).collect::<Vec<_>>(),
        vec![
            "0 A plan",
            "0 Name: plan.ldr",
            "1 4 10 -24 0.5 0 0 1 0 1 0 -1 0 0 s\\3001s01.dat",
            "0 STEP"
        ]
    );
    assert_eq!(parse_ldraw(text.as_bytes(), "plan.ldr").unwrap(), single);

    let dir = std::env::temp_dir().join(format!("brickgeom-writer-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("plan.mpd");
    write_ldraw(&path, &single).unwrap();
    let written = std::fs::read_to_string(&path).unwrap();
    assert!(written.starts_with("0 FILE plan.ldr\n"));
    assert_eq!(read_ldraw(&path).unwrap().models, single.models);
    // Only the output file is left behind (no temp files).
    assert_eq!(std::fs::read_dir(&dir).unwrap().count(), 1);
    assert!(matches!(
        write_ldraw(&dir.join("no/such/dir/x.ldr"), &single),
        Err(BrickGeomError::Io { .. })
    ));
    assert!(matches!(
        read_ldraw(&dir.join("missing.ldr")),
        Err(BrickGeomError::Io { .. })
    ));
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn values_built_in_memory_are_checked_by_the_reader_rules() {
    let good = LdrawRef {
        line: 0,
        colour: 4,
        position: [0.0, -24.0, 0.0],
        matrix: yaw_matrix(1).map(|r| r.map(f64::from)),
        name: "3001.dat".into(),
        is_submodel: false,
    };
    assert!(good.validate().is_ok());
    let bad_ref = |edit: fn(&mut LdrawRef), message: &str| {
        let mut r = good.clone();
        edit(&mut r);
        match r.validate() {
            Err(e @ BrickGeomError::InvalidLdraw { .. }) => {
                assert!(e.to_string().contains(message), "{e} lacks '{message}'")
            }
            other => panic!("expected InvalidLdraw, got {other:?}"),
        }
    };
    bad_ref(|r| r.name = " ".into(), "name is empty");
    bad_ref(|r| r.position[1] = f64::NAN, "position value NaN");
    bad_ref(|r| r.matrix[2][2] = f64::INFINITY, "matrix value inf");
    bad_ref(|r| r.position[0] = 2e6, "position value 2000000");
    bad_ref(|r| r.matrix = [[0.0; 3]; 3], "singular");

    let model = LdrawModel {
        name: "main.ldr".into(),
        title: String::new(),
        steps: vec![vec![good.clone()], vec![]],
    };
    let err = model.validate().unwrap_err();
    assert_eq!(
        err.to_string(),
        "LDraw model 'main.ldr': step 2 is empty (a step holds at least one reference)"
    );
    let unnamed = LdrawModel {
        name: String::new(),
        ..model.clone()
    };
    assert!(unnamed
        .validate()
        .unwrap_err()
        .to_string()
        .contains("name is empty"));
    let file = LdrawFile {
        name: "f.mpd".into(),
        models: vec![LdrawModel {
            steps: vec![vec![good]],
            ..model
        }],
        embedded_parts: vec![],
    };
    assert!(file.validate().is_ok());
    assert!(parse(&format!("1 4 0 0 0 {I} 3001.dat\n"))
        .unwrap()
        .validate()
        .is_ok());
}

/// Random models: steps of references with yaw matrices and lattice positions (plus some
/// arbitrary finite numbers), colours, and references to later submodels (no cycles).
fn arb_file() -> impl Strategy<Value = LdrawFile> {
    let name = "[a-z][a-z0-9 _-]{0,12}";
    let number = prop_oneof![
        (-400i32..400).prop_map(f64::from),
        (-1e5f64..1e5),
        (-1e3f64..1e3).prop_map(|v| (v * 8.0).round() / 8.0),
    ];
    let position = proptest::array::uniform3(number);
    let raw_ref = (0u8..4, position, -1i32..600, name, any::<bool>(), 0usize..8);
    let models = proptest::collection::vec(
        (
            "[a-z][a-z0-9 ]{0,10}",
            proptest::collection::vec(proptest::collection::vec(raw_ref, 1..5), 1..4),
        ),
        1..5,
    );
    models.prop_map(|models| {
        let n = models.len();
        let names: Vec<String> = (0..n).map(|i| format!("model {i}.ldr")).collect();
        let models = models
            .into_iter()
            .enumerate()
            .map(|(i, (title, steps))| LdrawModel {
                name: names[i].clone(),
                title: title.trim().to_string(),
                steps: steps
                    .into_iter()
                    .map(|step| {
                        step.into_iter()
                            .map(|(yaw, position, colour, part, sub, target)| {
                                // Submodel references only point forward: no cycles.
                                let child = i + 1 + target % n.max(1);
                                let is_submodel = sub && child < n;
                                LdrawRef {
                                    line: 0,
                                    colour,
                                    position,
                                    matrix: yaw_matrix(yaw).map(|r| r.map(f64::from)),
                                    name: if is_submodel {
                                        names[child].clone()
                                    } else {
                                        format!("{part}.dat")
                                    },
                                    is_submodel,
                                }
                            })
                            .collect()
                    })
                    .collect(),
            })
            .collect();
        LdrawFile {
            name: "random.mpd".into(),
            models,
            embedded_parts: vec![],
        }
    })
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(300))]

    #[test]
    fn write_then_read_round_trips(file in arb_file()) {
        prop_assert!(file.validate().is_ok());
        let text = write_ldraw_string(&file);
        let back = parse_ldraw(text.as_bytes(), &file.name).unwrap();
        prop_assert_eq!(&back, &file);
        prop_assert_eq!(back.flatten(), file.flatten());
    }

    #[test]
    fn lattice_pose_inverts_ldraw_placement(yaw in 0u8..4, t in proptest::array::uniform3(-4096i32..4096)) {
        let pose = Pose::new(yaw, t);
        let (p, m) = ldraw_placement(pose);
        let back = lattice_pose(p, m);
        prop_assert_eq!(back.pose, pose);
        prop_assert!(!back.off_lattice && !back.non_yaw);
    }
}
