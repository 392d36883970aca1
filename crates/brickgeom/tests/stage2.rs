//! Stage 2 on hand-built cases with known answers, from oracle detections (ground-truth
//! keypoints, rotation classes and visible masks).

use std::sync::Arc;

use brickgeom::camera::Camera;
use brickgeom::colours::ColourTable;
use brickgeom::raster::{RenderOptions, Rendered};
use brickgeom::scene::{render_assembly, MeshSource};
use brickgeom::stage2::{
    abys_ranked, abys_step, infer_step, rotation_class, Detection, InferOptions, TypeDetections,
    DETACHED_PENALTY,
};
use brickgeom::{Assembly, AttachKind, Component, GroundSearch, Pose};

const W: u32 = 256;

fn comp(id: &str) -> Arc<Component> {
    Arc::new(Component::primitive(id).unwrap())
}

fn camera_for(asm: &Assembly) -> Camera {
    let (lo, hi) = asm.bounds().unwrap();
    let mut pts = Vec::new();
    for x in [lo[0], hi[0] + 1] {
        for y in [lo[1], hi[1] + 1] {
            for z in [lo[2], hi[2] + 1] {
                pts.push([x as f64 * 10.0, y as f64 * 8.0, z as f64 * 10.0]);
            }
        }
    }
    Camera::new(30.0, 225.0, 0.0, 1.0, [0.0, 0.0])
        .unwrap()
        .fitted(&pts, 0.8)
        .unwrap()
}

/// `after` rendered with the built-in meshes and colours.
fn rendered(after: &Assembly, cam: &Camera) -> Rendered {
    render_assembly(
        after,
        cam,
        &RenderOptions::new(W, W),
        &ColourTable::builtin(),
        &MeshSource::builtin(),
    )
    .unwrap()
}

/// The pixels where instance `id` of `after` is visible.
fn mask_of(after: &Assembly, cam: &Camera, id: u32) -> Vec<bool> {
    rendered(after, cam)
        .ids
        .iter()
        .map(|&i| i == id as i32)
        .collect()
}

/// Oracle detections for the instances `new` (ids in `after`) of a step, grouped by component.
fn oracle(after: &Assembly, new: &[u32], cam: &Camera, jitter: f64) -> Vec<TypeDetections> {
    let r = rendered(after, cam);
    let mut types: Vec<TypeDetections> = Vec::new();
    for (k, &id) in new.iter().enumerate() {
        let inst = after.instance(id).unwrap();
        let c = inst.component.clone();
        let kps = c.keypoints();
        let kp = inst.pose.apply_ldu(kps[kps.len() - 1]);
        let (px, _) = cam.project([kp[0] as f64, kp[1] as f64, kp[2] as f64], W, W);
        // deterministic jitter pattern
        let a = k as f64 * 2.399;
        let px = [px[0] + jitter * a.cos(), px[1] + jitter * a.sin()];
        let mut rot = [0f32; 7];
        rot[rotation_class(c.symmetry, inst.pose.yaw) as usize] = 1.0;
        let det = Detection {
            keypoint: px,
            score: 1.0,
            rotation: Some(rot),
            mask: Some(r.ids.iter().map(|&i| i == id as i32).collect()),
        };
        match types
            .iter_mut()
            .find(|t| Arc::ptr_eq(&t.component, &c) || t.component.name == c.name)
        {
            Some(t) => {
                t.count += 1;
                t.detections.push(det);
            }
            None => types.push(TypeDetections {
                component: c,
                count: 1,
                detections: vec![det],
            }),
        }
    }
    types
}

/// Run stage 2 for the last `n_new` instances of `after`; assert every pose is recovered
/// (modulo symmetry, as a multiset per type) and return the attach kinds.
fn check_recovered(after: &Assembly, n_new: usize, jitter: f64) -> Vec<AttachKind> {
    let ids: Vec<u32> = after.instances().map(|(id, _)| id).collect();
    let (old, new) = ids.split_at(ids.len() - n_new);
    let mut base = Assembly::new();
    for &id in old {
        let i = after.instance(id).unwrap();
        base.add(i.component.clone(), i.pose).unwrap();
    }
    // the test layout itself must be a valid step
    let items: Vec<_> = new
        .iter()
        .map(|&id| {
            let i = after.instance(id).unwrap();
            (i.component.clone(), i.pose)
        })
        .collect();
    assert!(
        base.check_step(&items).iter().all(|r| r.is_ok()),
        "invalid test layout: {:?}",
        base.check_step(&items)
    );
    let cam = camera_for(after);
    let types = oracle(after, new, &cam, jitter);
    let preds = infer_step(&base, &cam, W, W, &types, &InferOptions::default()).unwrap();
    assert_eq!(preds.len(), n_new);
    let mut kinds = Vec::new();
    for (ti, t) in types.iter().enumerate() {
        let truth: Vec<Pose> = new
            .iter()
            .map(|&id| after.instance(id).unwrap())
            .filter(|i| i.component.name == t.component.name)
            .map(|i| i.pose)
            .collect();
        let mut unmatched = truth.clone();
        for p in preds.iter().filter(|p| p.type_index == ti) {
            let pose = p.pose.unwrap_or_else(|| panic!("no pose: {:?}", p.failure));
            let j = unmatched
                .iter()
                .position(|g| t.component.same_placement(g, &pose))
                .unwrap_or_else(|| {
                    panic!(
                        "{} predicted at {pose:?}, truth {truth:?}",
                        t.component.name
                    )
                });
            unmatched.remove(j);
            kinds.push(p.attach.unwrap());
        }
        assert!(unmatched.is_empty());
    }
    kinds
}

#[test]
fn brick_on_brick_at_every_offset_and_yaw() {
    let b = comp("3001");
    let mut base = Assembly::new();
    base.add(b.clone(), Pose::new(0, [0, 3, 0])).unwrap();
    for yaw in 0..2u8 {
        let cands = base.candidates(&b, yaw, GroundSearch::Off).unwrap();
        assert!(cands.len() > 10);
        for c in cands {
            let mut after = base.clone();
            after.add(b.clone(), c.pose).unwrap();
            assert_eq!(
                check_recovered(&after, 1, 0.0),
                vec![AttachKind::OnStuds],
                "{:?}",
                c.pose
            );
        }
    }
}

#[test]
fn attached_from_below() {
    // a floating brick (the base need not be connected), a plate overhanging it, and a 1x1
    // plate plugged into the overhang from below, off the ground
    let mut after = Assembly::new();
    after.add(comp("3001"), Pose::new(0, [0, 6, 0])).unwrap();
    after.add(comp("3020"), Pose::new(0, [6, 7, 0])).unwrap();
    after.add(comp("3024"), Pose::new(0, [9, 6, 1])).unwrap();
    assert_eq!(check_recovered(&after, 1, 0.0), vec![AttachKind::FromBelow]);
}

#[test]
fn empty_base_goes_on_the_ground() {
    let mut after = Assembly::new();
    after.add(comp("3003"), Pose::new(0, [5, 3, -3])).unwrap();
    assert_eq!(check_recovered(&after, 1, 0.0), vec![AttachKind::Ground]);
}

#[test]
fn asymmetric_slope_at_each_yaw() {
    for yaw in 0..4u8 {
        let mut after = Assembly::new();
        after.add(comp("3035"), Pose::new(0, [0, 1, 0])).unwrap();
        after.add(comp("3040b"), Pose::new(yaw, [1, 4, 1])).unwrap();
        assert_eq!(
            check_recovered(&after, 1, 0.0),
            vec![AttachKind::OnStuds],
            "yaw {yaw}"
        );
    }
}

#[test]
fn submodule_with_two_topmost_bricks_at_each_yaw() {
    let mut sub = Assembly::new();
    sub.add(comp("3020"), Pose::new(0, [0, 1, 0])).unwrap();
    sub.add(comp("3003"), Pose::new(0, [-2, 4, 0])).unwrap();
    sub.add(comp("3004"), Pose::new(1, [3, 4, 0])).unwrap();
    let sub = Arc::new(sub.to_component("pair").unwrap());
    assert_eq!(sub.topmost.len(), 2);
    for yaw in 0..4u8 {
        let mut after = Assembly::new();
        after.add(comp("41539"), Pose::new(0, [0, 1, 0])).unwrap();
        after.add(sub.clone(), Pose::new(yaw, [1, 1, -1])).unwrap();
        assert_eq!(
            check_recovered(&after, 1, 0.0),
            vec![AttachKind::OnStuds],
            "yaw {yaw}"
        );
    }
}

#[test]
fn tiled_floor_of_identical_plates_in_one_step() {
    let mut after = Assembly::new();
    after.add(comp("41539"), Pose::new(0, [0, 1, 0])).unwrap();
    for (x, z) in [(-4, -4), (4, -4), (-4, 4), (4, 4)] {
        after.add(comp("3031"), Pose::new(0, [x, 2, z])).unwrap();
    }
    let kinds = check_recovered(&after, 4, 0.0);
    assert!(kinds.iter().all(|&k| k == AttachKind::OnStuds));
}

#[test]
fn stack_in_one_step_places_the_bottom_first() {
    let mut after = Assembly::new();
    after.add(comp("3035"), Pose::new(0, [0, 1, 0])).unwrap();
    for k in 0..3 {
        after
            .add(comp("3003"), Pose::new(0, [2, 4 + 3 * k, 2]))
            .unwrap();
    }
    check_recovered(&after, 3, 0.0);
}

#[test]
fn one_pixel_of_keypoint_noise_is_tolerated() {
    let mut after = Assembly::new();
    after.add(comp("41539"), Pose::new(0, [0, 1, 0])).unwrap();
    after.add(comp("3001"), Pose::new(1, [2, 4, 0])).unwrap();
    after.add(comp("3022"), Pose::new(0, [-4, 2, 4])).unwrap();
    check_recovered(&after, 2, 1.0);
}

#[test]
fn bad_detections_fail_per_component_not_per_step() {
    let mut base = Assembly::new();
    base.add(comp("3001"), Pose::new(0, [0, 3, 0])).unwrap();
    let cam = camera_for(&base);
    let det = |k: [f64; 2]| Detection {
        keypoint: k,
        score: 1.0,
        rotation: None,
        mask: None,
    };
    // far outside the image: nothing fits; the type with no detections fails too
    let types = vec![
        TypeDetections {
            component: comp("3003"),
            count: 1,
            detections: vec![det([-5000.0, -5000.0])],
        },
        TypeDetections {
            component: comp("3024"),
            count: 2,
            detections: vec![],
        },
    ];
    let preds = infer_step(&base, &cam, W, W, &types, &InferOptions::default()).unwrap();
    assert_eq!(preds.len(), 3);
    assert!(preds
        .iter()
        .all(|p| p.pose.is_none() && p.failure.is_some()));
    // NaN keypoints and wrong mask sizes are errors naming the problem
    let nan = vec![TypeDetections {
        component: comp("3003"),
        count: 1,
        detections: vec![det([f64::NAN, 0.0])],
    }];
    assert!(infer_step(&base, &cam, W, W, &nan, &InferOptions::default()).is_err());
    let mut bad_mask = det([10.0, 10.0]);
    bad_mask.mask = Some(vec![true; 7]);
    let wrong = vec![TypeDetections {
        component: comp("3003"),
        count: 1,
        detections: vec![bad_mask],
    }];
    let err = infer_step(&base, &cam, W, W, &wrong, &InferOptions::default()).unwrap_err();
    assert!(err.to_string().contains("mask"));
}

#[test]
fn analysis_by_synthesis_finds_a_brick_from_its_mask() {
    let mut after = Assembly::new();
    after.add(comp("3035"), Pose::new(0, [0, 1, 0])).unwrap();
    after.add(comp("3040b"), Pose::new(3, [2, 4, -1])).unwrap();
    let mut base = Assembly::new();
    base.add(comp("3035"), Pose::new(0, [0, 1, 0])).unwrap();
    assert!(
        base.check(&comp("3040b"), &Pose::new(3, [2, 4, -1]))
            .is_ok(),
        "test layout"
    );
    let cam = camera_for(&after);
    let mask = mask_of(&after, &cam, 1);
    let out = abys_step(&base, &cam, W, W, &[(comp("3040b"), mask)], 60.0).unwrap();
    let (pose, iou, timed_out) = out[0];
    assert!(!timed_out && iou > 0.9, "iou {iou}");
    assert!(comp("3040b").same_placement(&pose.unwrap(), &Pose::new(3, [2, 4, -1])));
}

/// A primitive whose rotation classifier leans the wrong way: the mask decides when
/// `rotation_by_mask` is on, the class alone when it is off.
#[test]
fn mask_overrules_a_hesitant_rotation_class() {
    let mut after = Assembly::new();
    after.add(comp("3001"), Pose::new(0, [0, 3, 0])).unwrap();
    after.add(comp("3001"), Pose::new(1, [0, 6, 0])).unwrap();
    let ids: Vec<u32> = after.instances().map(|(id, _)| id).collect();
    let mut base = Assembly::new();
    let first = after.instance(ids[0]).unwrap();
    base.add(first.component.clone(), first.pose).unwrap();
    let cam = camera_for(&after);
    let mut types = oracle(&after, &ids[1..], &cam, 0.0);
    // 3001 is 2-fold symmetric: classes 1 (yaw 0/2) and 2 (yaw 1/3); the truth is yaw 1
    let mut rot = [0f32; 7];
    rot[1] = 0.6;
    rot[2] = 0.4;
    types[0].detections[0].rotation = Some(rot);
    let truth = after.instance(ids[1]).unwrap().pose;
    let by_mask = infer_step(&base, &cam, W, W, &types, &InferOptions::default()).unwrap();
    let pose = by_mask[0].pose.unwrap();
    assert!(
        comp("3001").same_placement(&pose, &truth),
        "{pose:?} vs {truth:?}"
    );
    let opts = InferOptions {
        rotation_by_mask: false,
        ..InferOptions::default()
    };
    let by_class = infer_step(&base, &cam, W, W, &types, &opts).unwrap();
    assert_eq!(by_class[0].pose.unwrap().yaw % 2, 0);
}

/// A part standing on the ground on its own, several studs from the base (the generator stands
/// parts anywhere in its build region): the wide ground search finds it where the picture
/// shows it, at every yaw; the search beside the base cannot.
#[test]
fn part_standing_alone_on_the_ground_is_found_where_the_picture_shows_it() {
    for (yaw, t) in [(0u8, [-14, 3, 2]), (1, [12, 3, -10]), (2, [3, 3, 16])] {
        let mut after = Assembly::new();
        after.add(comp("3001"), Pose::new(0, [0, 3, 0])).unwrap();
        after.add(comp("3039"), Pose::new(yaw, t)).unwrap();
        let mut base = Assembly::new();
        base.add(comp("3001"), Pose::new(0, [0, 3, 0])).unwrap();
        // far from the footprint grown by the part: outside the old ground search
        let (lo, hi) = base.bounds().unwrap();
        assert!(t[0] < lo[0] - 5 || t[0] > hi[0] + 5 || t[2] < lo[2] - 5 || t[2] > hi[2] + 5);
        let cam = camera_for(&after);
        let mask = mask_of(&after, &cam, 1);
        let narrow = abys_ranked(&base, &comp("3039"), &cam, W, W, &mask, 1, 60.0, false).unwrap();
        assert!(narrow
            .0
            .first()
            .is_none_or(|(p, _)| !comp("3039").same_placement(p, &Pose::new(yaw, t))));
        let (ranked, _) =
            abys_ranked(&base, &comp("3039"), &cam, W, W, &mask, 1, 60.0, true).unwrap();
        let (pose, iou) = ranked[0];
        // standing away from the base costs the score its penalty
        assert!(iou > 0.9 - DETACHED_PENALTY, "yaw {yaw}: iou {iou}");
        assert!(comp("3039").same_placement(&pose, &Pose::new(yaw, t)));
    }
}

/// Seen along the camera's rays, a part on top of a tall stack draws nearly the silhouette of
/// one standing on the ground far behind the stack: the part on the stack is taken.
#[test]
fn a_part_on_the_stack_beats_its_lookalike_on_the_ground_behind() {
    let mut after = Assembly::new();
    for y in [3, 6, 9, 12] {
        after.add(comp("3001"), Pose::new(0, [0, y, 0])).unwrap();
    }
    after.add(comp("3660"), Pose::new(1, [1, 15, 0])).unwrap();
    let mut base = Assembly::new();
    for y in [3, 6, 9, 12] {
        base.add(comp("3001"), Pose::new(0, [0, y, 0])).unwrap();
    }
    let cam = camera_for(&after);
    let mask = mask_of(&after, &cam, 4);
    let (ranked, _) =
        abys_ranked(&base, &comp("3660"), &cam, W, W, &mask, 200, 60.0, true).unwrap();
    let (pose, _) = ranked[0];
    assert!(
        comp("3660").same_placement(&pose, &Pose::new(1, [1, 15, 0])),
        "{pose:?}"
    );
}
