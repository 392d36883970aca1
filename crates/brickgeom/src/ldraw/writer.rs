//! Writing .ldr/.mpd files that LDraw tools (LeoCAD, LDView, LPub3D, Studio) open and that
//! [`parse_ldraw`](super::parse_ldraw) reads back to an equal [`LdrawFile`].
//!
//! Layout: a plain .ldr (`0 title`, `0 Name:`, references, `0 STEP` after each step) when the
//! file has one model named like the file and no embedded parts; otherwise an .mpd with one
//! `0 FILE name` ... `0 NOFILE` block per model, then the embedded parts verbatim. Numbers use
//! Rust's shortest round-trip formatting (`20`, `-0.5`, `0.7071067811865476`), so reading the
//! output gives back exactly the same values. Reference names are written with `\` separators.
//! A title that would read as a meta command (`STEP`, `!KEYWORD`, `Name:`, ...) is not written.

use std::fmt::Write as _;
use std::io::Write as _;
use std::path::Path;

use super::model::{is_meta, LdrawFile, LdrawModel, LdrawRef};
use crate::error::{BrickGeomError, Result};

/// The text of `file` in LDraw format (see the module docs for the layout).
pub fn write_ldraw_string(file: &LdrawFile) -> String {
    render(file, file.is_mpd_content())
}

/// Write `file` to `path` (.ldr or .mpd): the text goes to a temporary file in the same folder
/// that is then renamed over `path`, so a failure never leaves a half-written file. A path ending
/// in `.mpd` always gets the .mpd layout.
pub fn write_ldraw(path: &Path, file: &LdrawFile) -> Result<()> {
    let mpd = file.is_mpd_content()
        || path
            .extension()
            .is_some_and(|e| e.eq_ignore_ascii_case("mpd"));
    let text = render(file, mpd);
    let io_err = |p: &Path, e: std::io::Error| BrickGeomError::Io {
        path: p.display().to_string(),
        message: e.to_string(),
    };
    let base = path
        .file_name()
        .ok_or_else(|| BrickGeomError::Io {
            path: path.display().to_string(),
            message: "not a file path".into(),
        })?
        .to_string_lossy();
    let tmp = path.with_file_name(format!(".{base}.{}.tmp", std::process::id()));
    let written = std::fs::File::create(&tmp).and_then(|mut f| {
        f.write_all(text.as_bytes())?;
        f.sync_all()
    });
    if let Err(e) = written.and_then(|_| std::fs::rename(&tmp, path)) {
        let _ = std::fs::remove_file(&tmp);
        return Err(io_err(path, e));
    }
    Ok(())
}

fn render(file: &LdrawFile, mpd: bool) -> String {
    let mut out = String::new();
    for model in &file.models {
        if mpd {
            let _ = writeln!(out, "0 FILE {}", one_line(&model.name));
        }
        write_model(&mut out, model);
        if mpd {
            out.push_str("0 NOFILE\n");
        }
    }
    for part in &file.embedded_parts {
        let _ = writeln!(out, "0 FILE {}", one_line(&part.name));
        if !part.text.is_empty() {
            out.push_str(&part.text);
            out.push('\n');
        }
        out.push_str("0 NOFILE\n");
    }
    out
}

fn write_model(out: &mut String, model: &LdrawModel) {
    let title = one_line(&model.title);
    if !is_meta(&title) {
        let _ = writeln!(out, "0 {title}");
    }
    let _ = writeln!(out, "0 Name: {}", one_line(&model.name));
    for step in &model.steps {
        for r in step {
            write_ref(out, r);
        }
        out.push_str("0 STEP\n");
    }
}

fn write_ref(out: &mut String, r: &LdrawRef) {
    out.push_str("1 ");
    if r.colour >= 0x100_0000 {
        let _ = write!(out, "0x{:X}", r.colour);
    } else {
        let _ = write!(out, "{}", r.colour);
    }
    for v in r.position.iter().chain(r.matrix.iter().flatten()) {
        out.push(' ');
        out.push_str(&number(*v));
    }
    out.push(' ');
    out.push_str(&one_line(&r.name).replace('/', "\\"));
    out.push('\n');
}

/// Shortest text that parses back to exactly `v` (`-0` written as `0`).
fn number(v: f64) -> String {
    if v == 0.0 {
        "0".to_string()
    } else {
        format!("{v}")
    }
}

/// `s` on one line, trimmed (line feeds become spaces; the reader never produces them).
fn one_line(s: &str) -> String {
    s.replace('\n', " ").trim().to_string()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn numbers_round_trip_and_are_short() {
        for v in [20.0, -0.5, 0.1 + 0.2, 1e-17, -123456.789, 1e6] {
            assert_eq!(number(v).parse::<f64>().unwrap(), v);
        }
        assert_eq!(number(-0.0), "0");
        assert_eq!(number(20.0), "20");
        assert_eq!(number(-8.0), "-8");
    }
}
