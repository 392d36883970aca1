//! Statistics of generated manuals: `cargo run --release -p brickgeom --example synth_stats [N]`.
//! Prints steps, instances and submodules per manual, and the time per manual.

use brickgeom::colours::ColourTable;
use brickgeom::scene::MeshSource;
use brickgeom::synth::{generate, render_build, validate_build, SynthConfig};

fn main() {
    let n: u64 = std::env::args()
        .nth(1)
        .and_then(|s| s.parse().ok())
        .unwrap_or(20);
    let cfg = SynthConfig::default();
    let (src, colours) = (MeshSource::builtin(), ColourTable::builtin());
    let (mut steps, mut insts, mut subs, mut with_sub, mut sub_steps) =
        (0usize, 0usize, 0usize, 0usize, 0usize);
    let mut low_vis = 0usize;
    let mut total_vis = 0usize;
    let t0 = std::time::Instant::now();
    let mut t_render = 0.0;
    for seed in 0..n {
        let m = generate(&cfg, seed).expect("generate");
        if let Err(e) = validate_build(&m.main, &cfg) {
            println!("seed {seed}: {e}");
            continue;
        }
        for s in &m.submodules {
            validate_build(&s.build, &cfg).expect("valid submodule");
            sub_steps += s.build.steps.len();
        }
        steps += m.main.steps.len();
        insts += m.main.instances.len();
        subs += m.submodules.len();
        with_sub += usize::from(!m.submodules.is_empty());
        let t1 = std::time::Instant::now();
        let imgs = render_build(&m.main, &cfg, &src, &colours).expect("render");
        t_render += t1.elapsed().as_secs_f64();
        for im in &imgs {
            for v in &im.instances {
                total_vis += 1;
                if v.visible_fraction < cfg.visibility {
                    low_vis += 1;
                }
            }
        }
    }
    let dt = t0.elapsed().as_secs_f64();
    println!(
        "{n} manuals: {:.1} steps/manual (+{:.1} submodule steps), {:.1} instances/manual, {:.2} submodules/manual, {:.0}% with submodules; {low_vis}/{total_vis} instances below visibility; {:.1} ms/manual ({:.1} ms render), {:.1} main steps/s",
        steps as f64 / n as f64,
        sub_steps as f64 / n as f64,
        insts as f64 / n as f64,
        subs as f64 / n as f64,
        100.0 * with_sub as f64 / n as f64,
        1e3 * dt / n as f64,
        1e3 * t_render / n as f64,
        steps as f64 / dt
    );
}
