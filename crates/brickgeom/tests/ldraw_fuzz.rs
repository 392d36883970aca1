//! Fuzzing the LDraw reader: random bytes and mutations of real model files must give `Ok` or
//! `Err`, never a panic. (`examples/fuzz_ldraw.rs` runs the same mutations at larger scale.)

use std::path::PathBuf;
use std::sync::OnceLock;

use brickgeom::ldraw::{parse_ldraw, write_ldraw_string};
use proptest::prelude::*;

/// Real model files (empty when the shared folder is absent) plus a small built-in model.
fn seeds() -> &'static Vec<Vec<u8>> {
    static SEEDS: OnceLock<Vec<Vec<u8>>> = OnceLock::new();
    SEEDS.get_or_init(|| {
        let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../shared/real/models");
        let mut out = vec![b"0 FILE a.ldr\n0 Title\n1 4 10 -24 0 1 0 0 0 1 0 0 0 1 3001.dat\n0 STEP\n\
1 16 0 0 0 0 0 1 0 1 0 -1 0 0 b.ldr\n0 NOFILE\n0 FILE b.ldr\n1 16 20 0 0 1 0 0 0 1 0 0 0 1 3003.dat\n"
            .to_vec()];
        if let Ok(entries) = std::fs::read_dir(&dir) {
            let mut paths: Vec<PathBuf> = entries.flatten().map(|e| e.path()).collect();
            paths.sort();
            out.extend(paths.iter().filter_map(|p| std::fs::read(p).ok()));
        } else {
            eprintln!("note: no real models at {}, fuzzing the built-in model only", dir.display());
        }
        out
    })
}

/// One mutation of `bytes`, driven by `op` and two random numbers.
fn mutate(bytes: &[u8], op: u8, a: usize, b: usize) -> Vec<u8> {
    let mut v = bytes.to_vec();
    let len = v.len().max(1);
    let lines =
        |v: &[u8]| -> Vec<Vec<u8>> { v.split(|&c| c == b'\n').map(<[u8]>::to_vec).collect() };
    match op % 9 {
        0 => {
            if !v.is_empty() {
                v[a % len] ^= 1 << (b % 8);
            }
        }
        1 => v.truncate(a % len),
        2 => {
            let mut ls = lines(&v);
            if !ls.is_empty() {
                let i = a % ls.len();
                ls.remove(i);
            }
            v = ls.join(&b'\n');
        }
        3 => {
            let mut ls = lines(&v);
            if !ls.is_empty() {
                let i = a % ls.len();
                let l = ls[i].clone();
                ls.insert(b % (ls.len() + 1), l);
            }
            v = ls.join(&b'\n');
        }
        4 => {
            // Swap two whitespace-separated fields of one line.
            let mut ls = lines(&v);
            if !ls.is_empty() {
                let i = a % ls.len();
                let mut f: Vec<Vec<u8>> = ls[i].split(|&c| c == b' ').map(<[u8]>::to_vec).collect();
                let n = f.len();
                f.swap(a % n, b % n);
                ls[i] = f.join(&b' ');
            }
            v = ls.join(&b'\n');
        }
        5 => v.insert(a % (v.len() + 1), 0),
        6 => {
            let junk: &[&[u8]] = &[
                b" 1e308",
                b" NaN",
                b" -inf",
                b" 99999999999",
                b" 0x",
                b" \xff\xfe",
                b"\n0 FILE ",
                b"\n0 NOFILE\n",
                b"\n0 STEP\n",
                b"\n1 16 0 0 0 1 0 0 0 1 0 0 0 1 a.ldr\n",
            ];
            let j = junk[b % junk.len()];
            let at = a % (v.len() + 1);
            v.splice(at..at, j.iter().copied());
        }
        7 => {
            // Replace one byte by a random one.
            if !v.is_empty() {
                v[a % len] = (b % 256) as u8;
            }
        }
        _ => {
            // Delete a range.
            if !v.is_empty() {
                let s = a % len;
                let e = (s + b % 64).min(v.len());
                v.drain(s..e);
            }
        }
    }
    v
}

/// Parse, and when that succeeds also flatten and write (they must not panic either), and the
/// written text must parse back to the same file.
fn exercise(bytes: &[u8]) {
    if let Ok(file) = parse_ldraw(bytes, "fuzz.mpd") {
        // What the reader accepts passes the checks on values built in memory.
        file.validate().expect("a parsed file validates");
        let _ = file.flatten();
        let text = write_ldraw_string(&file);
        let back = parse_ldraw(text.as_bytes(), "fuzz.mpd").expect("written output parses");
        assert_eq!(back, file);
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 2000, ..ProptestConfig::default() })]

    #[test]
    fn random_bytes_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..400)) {
        exercise(&bytes);
    }

    #[test]
    fn random_ldraw_like_text_never_panics(lines in proptest::collection::vec(
        "(0|1|2|3|4|5|x)( [-0-9.eE]{1,6}){0,16}( [a-z.\\\\]{1,8})?", 0..20)) {
        exercise(lines.join("\n").as_bytes());
    }

    #[test]
    fn mutated_real_models_never_panic(
        seed in any::<usize>(),
        ops in proptest::collection::vec((any::<u8>(), any::<usize>(), any::<usize>()), 1..6),
    ) {
        let seeds = seeds();
        let mut bytes = seeds[seed % seeds.len()].clone();
        for (op, a, b) in ops {
            bytes = mutate(&bytes, op, a, b);
        }
        exercise(&bytes);
    }
}
