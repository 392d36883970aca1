//! Property tests of the lattice, components and assemblies.

use std::sync::Arc;

use brickgeom::lattice::{rotate_cell, rotate_point};
use brickgeom::{library, Assembly, AttachKind, BrickGeomError, Component, GroundSearch, Pose};
use proptest::prelude::*;

fn component(id: &str) -> Arc<Component> {
    Arc::new(Component::primitive(id).expect("library part"))
}

fn any_part() -> impl Strategy<Value = &'static str> {
    let ids = library().ids();
    (0..ids.len()).prop_map(move |i| ids[i])
}

/// A deterministic random connected assembly of `n` parts grown from a seed.
fn grow(seed: u64, n: usize) -> Assembly {
    let ids = library().ids();
    let mut state = seed
        .wrapping_mul(6364136223846793005)
        .wrapping_add(1442695040888963407);
    let mut next = move |m: usize| {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        (state % m as u64) as usize
    };
    let mut asm = Assembly::new();
    let mut tries = 0;
    while asm.len() < n && tries < 20 * n {
        tries += 1;
        let c = component(ids[next(ids.len())]);
        let yaw = next(4) as u8;
        let ground = if asm.is_empty() {
            GroundSearch::Region {
                x0: 0,
                x1: 0,
                z0: 0,
                z1: 0,
            }
        } else {
            GroundSearch::Off
        };
        let cands = asm.candidates(&c, yaw, ground).unwrap();
        if cands.is_empty() {
            continue;
        }
        let p = cands[next(cands.len())];
        asm.add(c, p.pose).unwrap();
    }
    asm
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 64, failure_persistence: None, ..ProptestConfig::default() })]

    #[test]
    fn four_quarter_turns_are_identity(x in -500i32..500, y in -50i32..50, z in -500i32..500, yaw in 0u8..4) {
        let mut p = [x, y, z];
        let mut c = [x, y, z];
        for _ in 0..4 {
            p = rotate_point(p, 1);
            c = rotate_cell(c, 1);
        }
        prop_assert_eq!(p, [x, y, z]);
        prop_assert_eq!(c, [x, y, z]);
        // yaw then its inverse is the identity on poses too
        let pose = Pose::new(yaw, [x, y, z]);
        let back = Pose::new((4 - yaw) % 4, [0, 0, 0]).compose(&pose);
        prop_assert_eq!(back.yaw, 0);
    }

    #[test]
    fn collision_is_symmetric(a in any_part(), b in any_part(), ya in 0u8..4, yb in 0u8..4,
                              dx in -6i32..6, dy in -4i32..4, dz in -6i32..6) {
        let (ca, cb) = (component(a), component(b));
        let pa = Pose::new(ya, [0, 20, 0]);
        let pb = Pose::new(yb, [dx, 20 + dy, dz]);
        let mut s1 = Assembly::new();
        s1.add(ca.clone(), pa).unwrap();
        let mut s2 = Assembly::new();
        s2.add(cb.clone(), pb).unwrap();
        prop_assert_eq!(s1.collision(&cb, &pb).is_some(), s2.collision(&ca, &pa).is_some());
    }

    #[test]
    fn brick_on_any_free_stud_is_connected(seed in 0u64..10_000, part in any_part(), yaw in 0u8..4) {
        let asm = grow(seed, 6);
        let c = component(part);
        let rot = Pose::new(yaw, [0, 0, 0]);
        for s in asm.free_studs() {
            for &a in &c.anti_studs {
                let ra = rot.apply_point(a);
                let pose = Pose::new(yaw, [s[0] - ra[0], s[1] - ra[1], s[2] - ra[2]]);
                match asm.check(&c, &pose) {
                    Ok(kind) => prop_assert!(matches!(kind, AttachKind::OnStuds)),
                    // the only acceptable failures are geometric ones, never "not connected"
                    Err(e) => prop_assert!(
                        matches!(e, BrickGeomError::Collision { .. } | BrickGeomError::BelowGround { .. }),
                        "unexpected {e:?}"
                    ),
                }
            }
        }
    }

    #[test]
    fn add_then_remove_restores_state(seed in 0u64..10_000, part in any_part(), yaw in 0u8..4) {
        let mut asm = grow(seed, 8);
        let before = asm.snapshot();
        let c = component(part);
        let cands = asm.candidates(&c, yaw, GroundSearch::Auto).unwrap();
        prop_assume!(!cands.is_empty());
        let p = cands[(seed as usize) % cands.len()];
        let id = asm.add(c.clone(), p.pose).unwrap();
        prop_assert_ne!(asm.snapshot(), before.clone());
        asm.remove(id).unwrap();
        prop_assert_eq!(asm.snapshot(), before);
    }

    #[test]
    fn grid_holds_exactly_the_voxels(seed in 0u64..10_000) {
        let asm = grow(seed, 10);
        let expected: usize = asm.instances().map(|(_, i)| i.component.voxels.len()).sum();
        let (lo, hi) = asm.bounds().unwrap();
        let occ = asm.occupancy(lo, hi);
        prop_assert_eq!(occ.iter().map(|&v| v as usize).sum::<usize>(), expected);
        let ids = asm.id_grid(lo, hi);
        for (id, inst) in asm.instances() {
            for v in &inst.voxels {
                let idx = [(v[0] - lo[0]) as usize, (v[1] - lo[1]) as usize, (v[2] - lo[2]) as usize];
                prop_assert_eq!(ids[idx], id as i32);
            }
        }
    }

    #[test]
    fn every_candidate_is_valid_and_every_check_agrees(seed in 0u64..10_000, part in any_part(), yaw in 0u8..4) {
        let asm = grow(seed, 5);
        let c = component(part);
        let cands = asm.candidates(&c, yaw, GroundSearch::Off).unwrap();
        for p in &cands {
            prop_assert_eq!(asm.check(&c, &p.pose).ok(), Some(p.kind));
            prop_assert!(p.kind != AttachKind::Ground || asm.attach_kinds(&c, &p.pose).len() == 1);
        }
        // candidate enumeration is deterministic
        prop_assert_eq!(asm.candidates(&c, yaw, GroundSearch::Off).unwrap(), cands);
    }
}

#[test]
fn brick_on_brick_offsets() {
    // A 2x4 on a 2x4 at yaw 0: every stud/anti-stud alignment that overlaps the top face.
    let c = component("3001");
    let mut asm = Assembly::new();
    asm.add(c.clone(), Pose::new(0, [0, 3, 0])).unwrap();
    let cands = asm.candidates(&c, 0, GroundSearch::Off).unwrap();
    assert!(cands
        .iter()
        .all(|p| p.pose.t[1] == 6 && p.kind == AttachKind::OnStuds));
    assert!(cands.iter().any(|p| p.pose.t == [0, 6, 0]));
    assert!(cands.iter().any(|p| p.pose.t == [6, 6, 2]));
    // nothing can hang under a brick that stands on the ground
    assert!(cands.iter().all(|p| p.kind != AttachKind::FromBelow));
}

#[test]
fn attach_from_below_and_ground() {
    let c = component("3001");
    let mut asm = Assembly::new();
    asm.add(c.clone(), Pose::new(0, [0, 6, 0])).unwrap();
    // a brick directly under, standing on the ground, also plugs into the anti-studs above
    let kinds = asm.attach_kinds(&c, &Pose::new(0, [0, 3, 0]));
    assert_eq!(kinds, vec![AttachKind::FromBelow, AttachKind::Ground]);
    assert_eq!(
        asm.check(&c, &Pose::new(0, [0, 3, 0])),
        Ok(AttachKind::FromBelow)
    );
    // floating far away: not connected
    assert_eq!(
        asm.check(&c, &Pose::new(0, [40, 20, 0])),
        Err(BrickGeomError::NotConnected)
    );
    // below ground
    assert!(matches!(
        asm.check(&c, &Pose::new(0, [40, 2, 0])),
        Err(BrickGeomError::BelowGround { .. })
    ));
    // absurd coordinates are an error, not a huge allocation
    assert!(matches!(
        asm.check(&c, &Pose::new(0, [1 << 30, 3, 0])),
        Err(BrickGeomError::OutOfRange { .. })
    ));
}

#[test]
fn check_step_allows_any_order_within_a_step() {
    let c = component("3001");
    let mut asm = Assembly::new();
    asm.add(c.clone(), Pose::new(0, [0, 3, 0])).unwrap();
    // second item rests on the first item of the same step, listed first
    let items = vec![
        (c.clone(), Pose::new(0, [0, 9, 0])),
        (c.clone(), Pose::new(0, [0, 6, 0])),
    ];
    let res = asm.check_step(&items);
    assert_eq!(res, vec![Ok(AttachKind::OnStuds), Ok(AttachKind::OnStuds)]);
    assert_eq!(asm.len(), 1, "check_step leaves the assembly unchanged");
    // two items in the same place: the second collides
    let items = vec![
        (c.clone(), Pose::new(0, [0, 6, 0])),
        (c.clone(), Pose::new(0, [0, 6, 0])),
    ];
    let res = asm.check_step(&items);
    assert!(res[0].is_ok());
    assert!(matches!(res[1], Err(BrickGeomError::Collision { .. })));
}

#[test]
fn submodule_union_symmetry_and_topmost() {
    // Two 2x2 bricks side by side, then capped by a 2x4 plate.
    let mut asm = Assembly::new();
    asm.add(component("3003"), Pose::new(0, [-2, 3, 0]))
        .unwrap();
    asm.add(component("3003"), Pose::new(0, [2, 3, 0])).unwrap();
    let sub = asm.to_component("pair").unwrap();
    assert!(sub.is_submodule);
    assert_eq!(sub.voxels.len(), 2 * component("3003").voxels.len());
    assert_eq!(
        sub.symmetry, 2,
        "a 2x4 block of two 2x2 bricks has 2-fold symmetry"
    );
    assert_eq!(sub.topmost.len(), 2, "both bricks are topmost");
    asm.add(component("3020"), Pose::new(0, [0, 4, 0])).unwrap();
    let sub = asm.to_component("capped").unwrap();
    assert_eq!(sub.topmost.len(), 1);
    assert_eq!(sub.bricks[sub.topmost[0]].part, "3020");
    // the studs covered by the plate are internal; only the plate's 8 studs stay exposed
    assert_eq!(sub.studs.len(), 8);
    // pose equality modulo symmetry: the 2x4 block rotated by 180 degrees about its centre
    let a = Pose::new(0, [0, 0, 0]);
    let b = Pose::new(2, [0, 0, 0]);
    assert!(sub.same_placement(&a, &b));
    assert!(!sub.same_placement(&a, &Pose::new(1, [0, 0, 0])));
}

#[test]
fn a_side_stud_tells_apart_turns_the_lattice_geometry_does_not() {
    // 87087 turned a quarter about its centre: the same voxels and vertical studs, but the side
    // stud points elsewhere (a different picture), so it is not the same placement
    let c = component("87087");
    assert_eq!(c.symmetry, 1);
    let a = Pose::new(0, [0, 5, -1]);
    for yaw in 1..4 {
        let b = Pose::new(yaw, [0, 5, -1]);
        assert_eq!(c.placed(&a), c.placed(&b), "a 1x1 brick's lattice geometry");
        assert!(!c.same_placement(&a, &b), "yaw {yaw}");
    }
    assert!(c.same_placement(&a, &a));
    // the same in a submodule: a 2x2 brick with an 87087 on it has no symmetry, while a 2x2
    // brick with a 1x1 brick on its centre has four quarter turns
    for (top, symmetry) in [("87087", 1), ("3005", 4)] {
        let mut asm = Assembly::new();
        asm.add(component("3003"), Pose::new(0, [0, 3, 0])).unwrap();
        asm.add(component(top), Pose::new(0, [0, 6, 0])).unwrap();
        assert_eq!(asm.to_component("s").unwrap().symmetry, symmetry, "{top}");
    }
}

#[test]
fn remove_unknown_instance_is_an_error() {
    let mut asm = Assembly::new();
    assert_eq!(
        asm.remove(3).unwrap_err(),
        BrickGeomError::NoSuchInstance { id: 3 }
    );
}

#[test]
fn a_turn_that_swaps_two_colours_is_a_different_placement() {
    // two 1x1 plates side by side: the geometry has a half-turn symmetry, but with two colours
    // the half turn swaps them (a different picture), so the submodule has none
    let pair = |a: i32, b: i32| {
        Component::from_bricks(
            "pair".into(),
            vec![
                brickgeom::component::Brick {
                    part: "3024",
                    pose: Pose::new(0, [0, 1, 0]),
                    colour: a,
                },
                brickgeom::component::Brick {
                    part: "3024",
                    pose: Pose::new(0, [1, 1, 0]),
                    colour: b,
                },
            ],
        )
        .unwrap()
    };
    let two = pair(4, 1);
    assert_eq!(two.shape_symmetry, 2, "the geometry alone");
    assert_eq!(two.symmetry, 1, "the colours break it");
    // the half turn about the pair's centre maps the voxels onto themselves
    let a = Pose::new(0, [0, 0, 0]);
    let b = Pose::new(2, [1, 0, 0]);
    assert_eq!(two.placed(&a), two.placed(&b));
    assert!(!two.same_placement(&a, &b));
    let one = pair(4, 4);
    assert_eq!((one.shape_symmetry, one.symmetry), (2, 2));
    assert!(one.same_placement(&a, &b));
    // and a primitive keeps its part's own symmetry for both
    let plate = component("3023");
    assert_eq!((plate.shape_symmetry, plate.symmetry), (2, 2));
}
