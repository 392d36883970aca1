//! Render styles (`raster::RenderStyle`): the default style draws exactly today's pictures.
//!
//! The reference hashes below were taken with the renderer as it was before render styles
//! existed (commit 60960c8); a change to any byte of the default picture, depth or id image
//! changes them.

use brickgeom::colours::ColourTable;
use brickgeom::raster::{render_marked, RenderItem, RenderOptions, Rendered};
use brickgeom::render_style::{LineColour, LineMode, Mark, RenderStyle, Shading};
use brickgeom::scene::MeshSource;
use brickgeom::synth::{generate, render_build, SynthConfig};

/// FNV-1a over bytes.
fn fnv(bytes: impl IntoIterator<Item = u8>) -> u64 {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for b in bytes {
        h ^= b as u64;
        h = h.wrapping_mul(0x0000_0100_0000_01b3);
    }
    h
}

fn hash_rendered(r: &Rendered) -> (u64, u64, u64) {
    (
        fnv(r.rgb.iter().copied()),
        fnv(r.ids.iter().flat_map(|i| i.to_le_bytes())),
        fnv(r.depth.iter().flat_map(|d| d.to_bits().to_le_bytes())),
    )
}

/// Hashes of the step images (rgb, ids) of a generated manual.
fn manual_hashes(seed: u64, size: u32, supersample: u32) -> (u64, u64) {
    let cfg = SynthConfig {
        image_size: size,
        supersample,
        ..SynthConfig::default()
    };
    let m = generate(&cfg, seed).unwrap();
    let imgs = render_build(
        &m.main,
        &cfg,
        &MeshSource::builtin(),
        &ColourTable::builtin(),
    )
    .unwrap();
    (
        fnv(imgs.iter().flat_map(|i| i.rgb.iter().copied())),
        fnv(imgs
            .iter()
            .flat_map(|i| i.ids.iter().flat_map(|d| d.to_le_bytes()))),
    )
}

/// One render of a whole generated shape at 512 px with 2 px lines (the dilation path).
fn big_render_hashes() -> (u64, u64, u64) {
    let cfg = SynthConfig::default();
    let m = generate(&cfg, 11).unwrap();
    let asm = m.main.assembly().unwrap();
    let cam = m.main.steps.last().unwrap().camera;
    let opts = RenderOptions {
        line_px: 2.0,
        ..RenderOptions::new(512, 384)
    };
    let r = brickgeom::scene::render_assembly(
        &asm,
        &cam,
        &opts,
        &ColourTable::builtin(),
        &MeshSource::builtin(),
    )
    .unwrap();
    hash_rendered(&r)
}

#[test]
#[ignore = "prints the current hashes (to take new references after a deliberate change)"]
fn print_reference_hashes() {
    println!("manual 3 256 ss1: {:x?}", manual_hashes(3, 256, 1));
    println!("manual 4 192 ss3: {:x?}", manual_hashes(4, 192, 3));
    println!("big: {:x?}", big_render_hashes());
}

#[test]
fn default_style_draws_todays_pictures() {
    assert_eq!(
        manual_hashes(3, 256, 1),
        (0xb953a0afa0136e22, 0xec84b27a757d8b1f)
    );
    assert_eq!(
        manual_hashes(4, 192, 3),
        (0x20eefb0704b214f5, 0xb96c5bc96efb681c)
    );
    assert_eq!(
        big_render_hashes(),
        (0x9ae9c2c0e86deba4, 0xb73b384b0871151b, 0xbe40cdbe7706c547)
    );
}

/// The last step of manual 3: its items (by instance id), camera and the ids it adds.
fn scene() -> (brickgeom::Assembly, brickgeom::camera::Camera, Vec<u32>) {
    let m = generate(&SynthConfig::default(), 3).unwrap();
    let step = m.main.steps.last().unwrap();
    let asm = m.main.assembly().unwrap();
    let new = step.instances.iter().map(|&i| i as u32).collect();
    (asm, step.camera, new)
}

fn draw(style: RenderStyle, marks: &[Mark]) -> Rendered {
    let (asm, cam, _) = scene();
    let mut items_meshes = Vec::new();
    let src = MeshSource::builtin();
    let colours = ColourTable::builtin();
    let mut placed = Vec::new();
    for (id, inst) in asm.instances() {
        for b in &inst.component.bricks {
            let c = if b.colour == brickgeom::component::MAIN_COLOUR {
                inst.colour
            } else {
                b.colour
            };
            items_meshes.push(src.mesh(b.part).unwrap());
            placed.push((inst.pose.compose(&b.pose), colours.rgb(c), id));
        }
    }
    let items: Vec<RenderItem> = items_meshes
        .iter()
        .zip(&placed)
        .map(|(m, &(pose, colour, id))| RenderItem {
            mesh: m,
            pose,
            colour,
            id,
        })
        .collect();
    let opts = RenderOptions {
        style,
        ..RenderOptions::new(256, 256)
    };
    render_marked(&items, &cam, &opts, marks).unwrap()
}

fn dark_pixels(r: &Rendered) -> usize {
    r.rgb
        .chunks(3)
        .filter(|p| p.iter().all(|&c| c < 50))
        .count()
}

#[test]
fn styles_never_change_ids_or_depth() {
    let plain = draw(RenderStyle::default(), &[]);
    let (_, _, new) = scene();
    let mut marks = vec![Mark::Old; 200];
    for &i in &new {
        marks[i as usize] = Mark::New;
    }
    for style in [
        RenderStyle {
            lines: LineMode::None,
            shading: Shading::Flat,
            ..RenderStyle::default()
        },
        RenderStyle {
            front_lines: true,
            highlight: Some([255, 0, 0]),
            highlight_px: 3.0,
            fade: 0.5,
            saturation: 0.5,
            ..RenderStyle::default()
        },
        RenderStyle {
            light: [0.5, -0.2, -1.0],
            shading: Shading::Specular,
            specular: 0.6,
            line_colour: LineColour::Part { darken: 0.5 },
            ..RenderStyle::default()
        },
    ] {
        let r = draw(style, &marks);
        assert_eq!(r.ids, plain.ids);
        assert_eq!(
            r.depth.iter().map(|d| d.to_bits()).collect::<Vec<_>>(),
            plain.depth.iter().map(|d| d.to_bits()).collect::<Vec<_>>()
        );
        assert_eq!(r.visible_samples, plain.visible_samples);
        assert_ne!(r.rgb, plain.rgb);
    }
}

#[test]
fn fewer_lines_fewer_dark_pixels() {
    let all = dark_pixels(&draw(RenderStyle::default(), &[]));
    let parts = dark_pixels(&draw(
        RenderStyle {
            lines: LineMode::Parts,
            ..RenderStyle::default()
        },
        &[],
    ));
    let none = dark_pixels(&draw(
        RenderStyle {
            lines: LineMode::None,
            ..RenderStyle::default()
        },
        &[],
    ));
    assert!(none < parts && parts < all, "{none} {parts} {all}");
}

#[test]
fn front_lines_outline_the_left_contour() {
    // The first part pixel of each row is a line (dark or the grey of dark parts) with front
    // lines, and a face colour without them.
    let count = |r: &Rendered| {
        let mut lines = 0;
        for y in 0..256usize {
            if let Some(x) = (0..256usize).find(|&x| r.ids[y * 256 + x] >= 0) {
                let p = &r.rgb[(y * 256 + x) * 3..(y * 256 + x) * 3 + 3];
                lines += usize::from(p.iter().all(|&c| c < 100) || p == [95, 95, 95]);
            }
        }
        lines
    };
    let plain = count(&draw(RenderStyle::default(), &[]));
    let front = count(&draw(
        RenderStyle {
            front_lines: true,
            ..RenderStyle::default()
        },
        &[],
    ));
    assert!(front > plain + 20, "{front} vs {plain}");
}

#[test]
fn highlight_and_fade_follow_the_marks() {
    let (_, _, new) = scene();
    let mut marks = vec![Mark::Old; 200];
    for &i in &new {
        marks[i as usize] = Mark::New;
    }
    let style = RenderStyle {
        highlight: Some([255, 0, 255]),
        fade: 0.6,
        ..RenderStyle::default()
    };
    let plain = draw(RenderStyle::default(), &marks);
    let r = draw(style, &marks);
    let magenta: Vec<usize> = (0..256 * 256)
        .filter(|&i| r.rgb[i * 3..i * 3 + 3] == [255, 0, 255])
        .collect();
    assert!(magenta.len() > 50);
    // the highlight is drawn on or next to new instances
    let near_new = |i: usize| {
        let (x, y) = ((i % 256) as i64, (i / 256) as i64);
        (-2..=2).any(|dy| {
            (-2..=2).any(|dx| {
                let (u, v) = (x + dx, y + dy);
                (0..256).contains(&u)
                    && (0..256).contains(&v)
                    && new.contains(&(r.ids[(v * 256 + u) as usize] as u32))
            })
        })
    };
    assert!(magenta.iter().all(|&i| near_new(i)));
    // old instances are lighter, new ones (away from the highlight) unchanged
    let mean = |img: &Rendered, old: bool| {
        let (mut s, mut n) = (0f64, 0f64);
        for i in 0..256 * 256 {
            let id = r.ids[i];
            let lit = r.rgb[i * 3..i * 3 + 3] == [255, 0, 255];
            if id >= 0 && new.contains(&(id as u32)) != old && !lit {
                s += img.rgb[i * 3..i * 3 + 3]
                    .iter()
                    .map(|&c| c as f64)
                    .sum::<f64>();
                n += 1.0;
            }
        }
        s / n
    };
    assert!(mean(&r, true) > mean(&plain, true) + 40.0);
    assert_eq!(mean(&r, false), mean(&plain, false));
}

#[test]
fn light_direction_changes_face_shades() {
    let above = draw(RenderStyle::default(), &[]);
    let below = draw(
        RenderStyle {
            light: [0.45, -0.75, -0.5],
            ..RenderStyle::default()
        },
        &[],
    );
    let differ = above
        .rgb
        .chunks(3)
        .zip(below.rgb.chunks(3))
        .filter(|(a, b)| a != b)
        .count();
    let part = above.ids.iter().filter(|&&i| i >= 0).count();
    assert!(differ > part / 2, "{differ} of {part}");
}

#[test]
fn bad_styles_are_errors_not_panics() {
    let (asm, cam, _) = scene();
    for style in [
        RenderStyle {
            light: [0.0; 3],
            ..RenderStyle::default()
        },
        RenderStyle {
            highlight_px: 0.0,
            ..RenderStyle::default()
        },
        RenderStyle {
            ambient: f32::INFINITY,
            ..RenderStyle::default()
        },
    ] {
        let opts = RenderOptions {
            style,
            ..RenderOptions::new(64, 64)
        };
        let e = brickgeom::scene::render_assembly(
            &asm,
            &cam,
            &opts,
            &ColourTable::builtin(),
            &MeshSource::builtin(),
        )
        .unwrap_err();
        assert!(e.to_string().contains("style"), "{e}");
    }
}

/// Each pixel reports the world axis its visible face's normal lies closest to (what the camera
/// fit's shade per face axis groups by): the page none, a brick seen from high above mostly its
/// top (y), seen from near the ground mostly its sides (x and z, both of a three-quarter view).
#[test]
fn pixels_report_the_axis_of_their_face() {
    use brickgeom::camera::Camera;
    use brickgeom::Pose;
    use std::sync::Arc;
    let mut asm = brickgeom::Assembly::new();
    let brick = Arc::new(brickgeom::component::Component::primitive("3001").unwrap());
    asm.add(brick, Pose::new(0, [0, 3, 0])).unwrap();
    let corners: Vec<[f64; 3]> = [-40.0, 40.0]
        .iter()
        .flat_map(|&x| [0.0, 28.0].map(move |y| (x, y)))
        .flat_map(|(x, y)| [-20.0, 20.0].map(move |z| [x, y, z]))
        .collect();
    let share_up = |elevation: f64| {
        let cam = Camera::new(elevation, 30.0, 0.0, 1.0, [0.0, 0.0])
            .unwrap()
            .fitted(&corners, 0.8)
            .unwrap();
        let r = brickgeom::scene::render_assembly(
            &asm,
            &cam,
            &RenderOptions::new(128, 128),
            &ColourTable::builtin(),
            &MeshSource::builtin(),
        )
        .unwrap();
        assert_eq!(r.axes.len(), r.ids.len());
        for (a, i) in r.axes.iter().zip(&r.ids) {
            assert_eq!(
                *a < 0,
                *i < 0,
                "page pixels, and only they, have no face axis"
            );
        }
        let count = |k: i8| r.axes.iter().filter(|&&a| a == k).count() as f64;
        let drawn = count(0) + count(1) + count(2);
        (count(1) / drawn, count(0) / drawn, count(2) / drawn)
    };
    let (up, _, _) = share_up(85.0);
    assert!(up > 0.8, "from above, the top: {up}");
    let (up, x, z) = share_up(5.0);
    assert!(
        up < 0.3 && x > 0.1 && z > 0.1,
        "from the side: {up} {x} {z}"
    );
}
