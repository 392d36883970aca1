//! Line-level helpers shared by the LDraw model reader and the part geometry loader: byte
//! decoding, tokenising with a free-text tail, and checked number parsing. Nothing here panics.

use crate::error::{BrickGeomError, Result};

/// Largest |coordinate or matrix entry| accepted in an LDraw line (LDU); beyond it input is absurd.
pub const MAX_ABS_VALUE: f64 = 1e6;

/// Decode file bytes to text. NUL bytes mean a binary file (`Parse` at line 1); a UTF-8 BOM is
/// dropped; bytes that are not UTF-8 are read as Latin-1 (old LDraw files use it in comments).
pub(crate) fn decode(bytes: &[u8], file: &str) -> Result<String> {
    if bytes.contains(&0) {
        return Err(parse_err(
            file,
            1,
            "binary file (contains NUL bytes), not LDraw text",
        ));
    }
    let bytes = bytes.strip_prefix(b"\xEF\xBB\xBF").unwrap_or(bytes);
    Ok(match std::str::from_utf8(bytes) {
        Ok(s) => s.to_string(),
        Err(_) => bytes.iter().map(|&b| b as char).collect(),
    })
}

/// A `Parse` error at a 1-based line.
pub(crate) fn parse_err(file: &str, line: usize, message: impl Into<String>) -> BrickGeomError {
    BrickGeomError::Parse {
        file: file.to_string(),
        line,
        message: message.into(),
    }
}

/// The first `n` whitespace-separated tokens of `line` and the rest of the line (trimmed, inner
/// spaces kept), or `None` if the line has fewer than `n` tokens.
pub(crate) fn split_fields(line: &str, n: usize) -> Option<(Vec<&str>, &str)> {
    let mut fields = Vec::with_capacity(n);
    let mut rest = line.trim_start();
    while fields.len() < n {
        if rest.is_empty() {
            return None;
        }
        let end = rest.find(char::is_whitespace).unwrap_or(rest.len());
        fields.push(&rest[..end]);
        rest = rest[end..].trim_start();
    }
    Some((fields, rest.trim_end()))
}

/// A finite number with |value| <= [`MAX_ABS_VALUE`].
pub(crate) fn number(tok: &str, file: &str, line: usize) -> Result<f64> {
    let v: f64 = tok
        .parse()
        .map_err(|_| parse_err(file, line, format!("'{tok}' is not a number")))?;
    if !v.is_finite() {
        return Err(parse_err(
            file,
            line,
            format!("'{tok}' is not a finite number"),
        ));
    }
    if v.abs() > MAX_ABS_VALUE {
        return Err(parse_err(
            file,
            line,
            format!("value {tok} exceeds the supported magnitude {MAX_ABS_VALUE:e} LDU"),
        ));
    }
    Ok(v)
}

/// An LDraw colour code: decimal, or a direct colour written `0x2RRGGBB` (any hex that fits).
pub(crate) fn colour(tok: &str, file: &str, line: usize) -> Result<i32> {
    let parsed = match tok.strip_prefix("0x").or_else(|| tok.strip_prefix("0X")) {
        Some(hex) => u32::from_str_radix(hex, 16)
            .ok()
            .and_then(|v| i32::try_from(v).ok()),
        None => tok.parse::<i32>().ok(),
    };
    parsed.ok_or_else(|| parse_err(file, line, format!("'{tok}' is not a colour code")))
}

/// Numbers of a point list (`3 * k` tokens) as points.
pub(crate) fn points<const K: usize>(
    toks: &[&str],
    file: &str,
    line: usize,
) -> Result<[[f64; 3]; K]> {
    let mut out = [[0.0; 3]; K];
    if toks.len() != 3 * K {
        return Err(parse_err(file, line, "wrong number of coordinates"));
    }
    for (i, tok) in toks.iter().enumerate() {
        out[i / 3][i % 3] = number(tok, file, line)?;
    }
    Ok(out)
}

/// Determinant of a 3x3 matrix.
pub(crate) fn det3(m: &[[f64; 3]; 3]) -> f64 {
    m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1])
        - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
        + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0])
}

/// A type-1 line's numeric part: colour, position and row-major matrix `a..i`.
pub(crate) struct Type1 {
    pub colour: i32,
    pub position: [f64; 3],
    pub matrix: [[f64; 3]; 3],
}

/// Parse the 13 numeric fields after the `1` of a type-1 line (`colour x y z a b c d e f g h i`).
pub(crate) fn type1_numbers(fields: &[&str], file: &str, line: usize) -> Result<Type1> {
    if fields.len() != 13 {
        return Err(parse_err(file, line, "type-1 line needs 15 fields"));
    }
    let colour = colour(fields[0], file, line)?;
    let mut v = [0.0; 12];
    for (slot, tok) in v.iter_mut().zip(&fields[1..]) {
        *slot = number(tok, file, line)?;
    }
    Ok(Type1 {
        colour,
        position: [v[0], v[1], v[2]],
        matrix: [[v[3], v[4], v[5]], [v[6], v[7], v[8]], [v[9], v[10], v[11]]],
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn split_keeps_inner_spaces_of_the_tail() {
        let (f, rest) = split_fields("1 16 0 0 0  my model.ldr ", 5).unwrap();
        assert_eq!(f, vec!["1", "16", "0", "0", "0"]);
        assert_eq!(rest, "my model.ldr");
        assert!(split_fields("1 2", 3).is_none());
    }

    #[test]
    fn numbers_are_checked() {
        assert_eq!(number("-1.5", "f", 1).unwrap(), -1.5);
        assert!(number("nan", "f", 1).is_err());
        assert!(number("inf", "f", 1).is_err());
        assert!(number("1e7", "f", 1).is_err());
        assert!(number("x", "f", 1).is_err());
        assert_eq!(colour("0x2FF0000", "f", 1).unwrap(), 0x2FF0000);
        assert!(colour("0xFFFFFFFFF", "f", 1).is_err());
    }

    #[test]
    fn latin1_and_binary() {
        assert_eq!(decode(b"0 caf\xe9", "f").unwrap(), "0 caf\u{e9}");
        assert!(decode(b"0 a\0b", "f").is_err());
    }
}
