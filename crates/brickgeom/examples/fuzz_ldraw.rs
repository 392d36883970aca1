//! Deterministic fuzzing of the LDraw reader and writer.
//!
//! `cargo run -p brickgeom --example fuzz_ldraw [N] [MODELS_DIR]` runs N inputs (default 100000):
//! a quarter random bytes, the rest real model files (default `../shared/real/models`) with 1-5
//! random mutations each (bit flips, truncation, line deletion/duplication, field swaps, inserted
//! NUL bytes, huge or non-finite numbers, stray FILE/STEP lines). Each input is parsed under
//! `catch_unwind`; parsed files are also flattened, written and re-read (which must give the same
//! file). Prints `N inputs, K parsed ok, E errors, P panics` and exits 1 on any panic.

use std::path::PathBuf;

use brickgeom::ldraw::{parse_ldraw, write_ldraw_string};

/// xorshift64*: small, deterministic, no dependencies.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_F491_4F6C_DD1D)
    }

    fn below(&mut self, n: usize) -> usize {
        (self.next() % n.max(1) as u64) as usize
    }
}

const JUNK: &[&[u8]] = &[
    b" 1e308",
    b" NaN",
    b" -inf",
    b" 99999999999",
    b" 0x",
    b" \xff\xfe",
    b"\n0 FILE ",
    b"\n0 NOFILE\n",
    b"\n0 STEP\n",
    b"\n0 !DATA x.png\n",
    b"\n1 16 0 0 0 1 0 0 0 1 0 0 0 1 a.ldr\n",
    b"\n1 16 0 0 0 0 0 0 0 0 0 0 0 0 a.dat\n",
    b"\x00",
];

fn split_lines(v: &[u8]) -> Vec<Vec<u8>> {
    v.split(|&c| c == b'\n').map(<[u8]>::to_vec).collect()
}

fn mutate(v: &mut Vec<u8>, rng: &mut Rng) {
    let len = v.len();
    match rng.below(9) {
        0 if len > 0 => {
            let i = rng.below(len);
            v[i] ^= 1 << rng.below(8);
        }
        1 => v.truncate(rng.below(len + 1)),
        2..=4 => {
            let mut lines = split_lines(v);
            let i = rng.below(lines.len());
            match rng.below(3) {
                0 => {
                    lines.remove(i);
                }
                1 => {
                    let line = lines[i].clone();
                    let at = rng.below(lines.len() + 1);
                    lines.insert(at, line);
                }
                _ => {
                    let mut fields: Vec<Vec<u8>> =
                        lines[i].split(|&c| c == b' ').map(<[u8]>::to_vec).collect();
                    let (a, b) = (rng.below(fields.len()), rng.below(fields.len()));
                    fields.swap(a, b);
                    lines[i] = fields.join(&b' ');
                }
            }
            *v = lines.join(&b'\n');
        }
        5..=6 => {
            let junk = JUNK[rng.below(JUNK.len())];
            let at = rng.below(len + 1);
            v.splice(at..at, junk.iter().copied());
        }
        7 if len > 0 => {
            let i = rng.below(len);
            v[i] = rng.next() as u8;
        }
        _ if len > 0 => {
            let start = rng.below(len);
            let end = (start + rng.below(64)).min(len);
            v.drain(start..end);
        }
        _ => {}
    }
}

/// Ok(true) parsed, Ok(false) rejected with an error; a panic propagates.
fn exercise(bytes: &[u8]) -> bool {
    match parse_ldraw(bytes, "fuzz.mpd") {
        Ok(file) => {
            let _ = file.flatten();
            let text = write_ldraw_string(&file);
            let back = parse_ldraw(text.as_bytes(), "fuzz.mpd").expect("written output parses");
            assert_eq!(back, file, "write/read round trip");
            true
        }
        Err(_) => false,
    }
}

fn main() {
    let mut args = std::env::args().skip(1);
    let n: usize = args.next().and_then(|a| a.parse().ok()).unwrap_or(100_000);
    let dir = args.next().map(PathBuf::from).unwrap_or_else(|| {
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../shared/real/models")
    });
    let mut seeds: Vec<Vec<u8>> = vec![b"0 FILE a.ldr\n0 Title\n1 4 10 -24 0 1 0 0 0 1 0 0 0 1 3001.dat\n\
0 STEP\n1 16 0 0 0 0 0 1 0 1 0 -1 0 0 b.ldr\n0 NOFILE\n0 FILE b.ldr\n1 16 20 0 0 1 0 0 0 1 0 0 0 1 3003.dat\n"
        .to_vec()];
    let mut paths: Vec<PathBuf> = std::fs::read_dir(&dir)
        .map(|entries| entries.flatten().map(|e| e.path()).collect())
        .unwrap_or_default();
    paths.sort();
    seeds.extend(paths.iter().filter_map(|p| std::fs::read(p).ok()));
    eprintln!("{} seed files from {}", seeds.len(), dir.display());
    // Keep the default hook from printing every caught panic; count them instead.
    std::panic::set_hook(Box::new(|_| {}));
    let mut rng = Rng(0x9E37_79B9_7F4A_7C15);
    let (mut ok, mut errors, mut panics) = (0usize, 0usize, 0usize);
    for i in 0..n {
        let input = if i % 4 == 0 {
            let len = rng.below(512);
            (0..len).map(|_| rng.next() as u8).collect()
        } else {
            let mut v = seeds[rng.below(seeds.len())].clone();
            for _ in 0..1 + rng.below(5) {
                mutate(&mut v, &mut rng);
            }
            v
        };
        match std::panic::catch_unwind(|| exercise(&input)) {
            Ok(true) => ok += 1,
            Ok(false) => errors += 1,
            Err(_) => {
                panics += 1;
                let path = std::env::temp_dir().join(format!("fuzz_ldraw_panic_{i}.mpd"));
                if std::fs::write(&path, &input).is_ok() {
                    eprintln!("panic on input {i}, saved to {}", path.display());
                }
            }
        }
    }
    println!("{n} inputs, {ok} parsed ok, {errors} errors, {panics} panics");
    if panics > 0 {
        std::process::exit(1);
    }
}
