//! LDraw colour codes -> RGB. A built-in table of the common solid and transparent colours
//! (values and edge colours as in the official LDConfig.ldr), optionally replaced by a library's
//! LDConfig.ldr; and LDraw's colour inheritance ([`resolve_colour`]).

use std::collections::HashMap;
use std::path::Path;
use std::sync::OnceLock;

use crate::component::MAIN_COLOUR;
use crate::error::{BrickGeomError, Result};

/// (code, name, rgb) of the built-in colours.
const BUILTIN: &[(i32, &str, u32)] = &[
    (0, "Black", 0x1B2A34),
    (1, "Blue", 0x1E5AA8),
    (2, "Green", 0x00852B),
    (3, "Dark_Turquoise", 0x069D9F),
    (4, "Red", 0xB40000),
    (5, "Dark_Pink", 0xD3359D),
    (6, "Brown", 0x543324),
    (7, "Light_Grey", 0x8A928D),
    (8, "Dark_Grey", 0x545955),
    (9, "Light_Blue", 0x97CBD9),
    (10, "Bright_Green", 0x58AB41),
    (11, "Light_Turquoise", 0x00AAA4),
    (12, "Salmon", 0xF06D61),
    (13, "Pink", 0xF6A9BB),
    (14, "Yellow", 0xFAC80A),
    (15, "White", 0xF4F4F4),
    (17, "Light_Green", 0xADD9A8),
    (18, "Light_Yellow", 0xFFD67F),
    (19, "Tan", 0xD7BA8C),
    (20, "Light_Violet", 0xAFBED6),
    (22, "Purple", 0x671F81),
    (23, "Dark_Blue_Violet", 0x0E3E9A),
    (25, "Orange", 0xD67923),
    (26, "Magenta", 0x901F76),
    (27, "Lime", 0xA5CA18),
    (28, "Dark_Tan", 0x897D62),
    (29, "Bright_Pink", 0xFF9ECD),
    (33, "Trans_Dark_Blue", 0x0020A0),
    (34, "Trans_Green", 0x237841),
    (36, "Trans_Red", 0xC91A09),
    (40, "Trans_Brown", 0x635F52),
    (41, "Trans_Medium_Blue", 0x559AB7),
    (43, "Trans_Light_Blue", 0xAEE9EF),
    (46, "Trans_Yellow", 0xF5CD2F),
    (47, "Trans_Clear", 0xFCFCFC),
    (57, "Trans_Orange", 0xF08F1C),
    (70, "Reddish_Brown", 0x5F3109),
    (71, "Light_Bluish_Grey", 0x969696),
    (72, "Dark_Bluish_Grey", 0x646464),
    (73, "Medium_Blue", 0x7396C8),
    (74, "Medium_Green", 0x7FC475),
    (84, "Medium_Nougat", 0xAA7D55),
    (85, "Medium_Lilac", 0x441A91),
    (92, "Nougat", 0xBB805A),
    (191, "Bright_Light_Orange", 0xFCAC00),
    (212, "Bright_Light_Blue", 0x9DC3F7),
    (226, "Bright_Light_Yellow", 0xFFEC6C),
    (272, "Dark_Blue", 0x19325A),
    (288, "Dark_Green", 0x00451A),
    (308, "Dark_Brown", 0x352100),
    (320, "Dark_Red", 0x720012),
    (321, "Dark_Azure", 0x469BC3),
    (322, "Medium_Azure", 0x68C3E2),
    (326, "Yellowish_Green", 0xE2F99A),
    (330, "Olive_Green", 0x77774E),
    (378, "Sand_Green", 0x708E7C),
    (379, "Sand_Blue", 0x70819A),
    (484, "Dark_Orange", 0x91501C),
];

/// Edge colours (`EDGE` in LDConfig.ldr, 2024-04-05) of the built-in colours that differ from
/// [`DEFAULT_EDGE_RGB`]; every other built-in colour has that edge.
const BUILTIN_EDGES: &[(i32, u32)] = &[
    (0, 0x808080),
    (6, 0x1E1E1E),
    (33, 0x000B38),
    (34, 0x174F2B),
    (36, 0x660D05),
    (40, 0x2A2823),
    (41, 0x326276),
    (43, 0x59D1DE),
    (46, 0xB49208),
    (47, 0xC9C9C9),
    (57, 0x9E5C0A),
    (70, 0x808080),
    (288, 0x808080),
    (308, 0x808080),
];

/// Colour used for codes that are neither in the table nor direct colours.
pub const UNKNOWN_RGB: [u8; 3] = [160, 160, 160];

/// LDraw's edge colour code 24: on a line, "the edge colour (complement) of the colour of the line
/// that references this file".
pub const EDGE_COLOUR_CODE: i32 = 24;

/// The edge colour taken for a colour the table knows no edge for (a direct colour, a code outside
/// the table): `#333333`, the edge LDConfig.ldr gives most colours.
pub const DEFAULT_EDGE_RGB: [u8; 3] = [0x33, 0x33, 0x33];

/// The LDraw direct colour code (`0x2RRGGBB`) of an RGB value.
pub fn direct_colour(rgb: [u8; 3]) -> i32 {
    0x200_0000 | (rgb[0] as i32) << 16 | (rgb[1] as i32) << 8 | rgb[2] as i32
}

/// LDraw's colour inheritance with the built-in table ([`ColourTable::resolve`]): the colour a
/// line written in `code` has when the file holding it is referenced in colour `inherited`.
pub fn resolve_colour(code: i32, inherited: i32) -> i32 {
    if code != MAIN_COLOUR && code != EDGE_COLOUR_CODE {
        return code; // the common case: no table needed
    }
    static TABLE: OnceLock<ColourTable> = OnceLock::new();
    TABLE
        .get_or_init(ColourTable::builtin)
        .resolve(code, inherited)
}

fn rgb_of(v: u32) -> [u8; 3] {
    [(v >> 16) as u8, (v >> 8) as u8, v as u8]
}

/// A colour table: code -> (name, rgb).
#[derive(Debug, Clone)]
pub struct ColourTable {
    map: HashMap<i32, (String, [u8; 3])>,
    /// code -> edge colour (`EDGE` of LDConfig.ldr).
    edges: HashMap<i32, [u8; 3]>,
}

impl Default for ColourTable {
    fn default() -> Self {
        Self::builtin()
    }
}

impl ColourTable {
    /// The built-in table.
    pub fn builtin() -> Self {
        ColourTable {
            map: BUILTIN
                .iter()
                .map(|&(c, n, v)| (c, (n.to_string(), rgb_of(v))))
                .collect(),
            edges: BUILTIN
                .iter()
                .map(|&(c, _, _)| {
                    let edge = BUILTIN_EDGES.iter().find(|&&(e, _)| e == c);
                    (c, edge.map_or(DEFAULT_EDGE_RGB, |&(_, v)| rgb_of(v)))
                })
                .collect(),
        }
    }

    /// The built-in table updated from `LDConfig.ldr` text (`0 !COLOUR name CODE c VALUE #rrggbb
    /// EDGE #rrggbb`; an `EDGE` given as a colour code takes that code's value).
    pub fn with_ldconfig(text: &str) -> Self {
        let mut t = Self::builtin();
        for line in text.lines() {
            let f: Vec<&str> = line.split_whitespace().collect();
            if f.len() < 7 || f[0] != "0" || f[1] != "!COLOUR" {
                continue;
            }
            let field = |key: &str| f.iter().position(|&x| x == key).and_then(|i| f.get(i + 1));
            let code = field("CODE").and_then(|c| c.parse::<i32>().ok());
            let value = field("VALUE")
                .and_then(|v| v.strip_prefix('#'))
                .and_then(|v| u32::from_str_radix(v, 16).ok());
            if let (Some(c), Some(v)) = (code, value) {
                t.map.insert(c, (f[2].to_string(), rgb_of(v)));
                let edge = field("EDGE").and_then(|e| match e.strip_prefix('#') {
                    Some(hex) => u32::from_str_radix(hex, 16).ok().map(rgb_of),
                    None => e
                        .parse::<i32>()
                        .ok()
                        .and_then(|k| t.map.get(&k))
                        .map(|x| x.1),
                });
                match edge {
                    Some(e) => t.edges.insert(c, e),
                    None => t.edges.remove(&c),
                };
            }
        }
        t
    }

    /// The table of an LDraw library root (its `LDConfig.ldr`).
    pub fn load(root: &Path) -> Result<Self> {
        let path = root.join("LDConfig.ldr");
        let text = std::fs::read_to_string(&path).map_err(|e| BrickGeomError::Io {
            path: path.display().to_string(),
            message: e.to_string(),
        })?;
        Ok(Self::with_ldconfig(&text))
    }

    /// RGB of a code: table colours, LDraw direct colours (`0x2RRGGBB`), else a neutral grey.
    pub fn rgb(&self, code: i32) -> [u8; 3] {
        if let Some((_, rgb)) = self.map.get(&code) {
            return *rgb;
        }
        if (0x200_0000..=0x2FF_FFFF).contains(&code) {
            return rgb_of(code as u32 & 0xFF_FFFF);
        }
        UNKNOWN_RGB
    }

    /// The edge colour of a code in the table (`EDGE` of LDConfig.ldr), if the table has one.
    pub fn edge(&self, code: i32) -> Option<[u8; 3]> {
        self.edges.get(&code).copied()
    }

    /// LDraw's colour inheritance: the colour of a line written in `code` inside a file that is
    /// referenced in colour `inherited`. Applied at every level of submodels, from the part up to
    /// the main model (which nothing references: there `inherited` is 16).
    /// - 16 (main colour) is `inherited`, so it stays 16 at the top level.
    /// - 24 (edge colour) is the edge colour of `inherited` as a direct colour `0x2RRGGBB`, and
    ///   [`DEFAULT_EDGE_RGB`] for a colour the table knows no edge for (direct colours, so every
    ///   edge colour resolved below; codes outside the table; 24 in the built-in table);
    ///   it stays 24 only while `inherited` is 16 (nothing above has set a colour yet).
    /// - Any other code (a table colour, a direct colour `0x2RRGGBB`) is the line's own.
    ///
    /// Resolving bottom-up (a submodel's bricks first against the reference placing them, then
    /// against the next reference up) gives what resolving top-down gives:
    /// `resolve(resolve(x, a), b) == resolve(x, resolve(a, b))`.
    pub fn resolve(&self, code: i32, inherited: i32) -> i32 {
        match (code, inherited) {
            (MAIN_COLOUR, c) => c,
            (EDGE_COLOUR_CODE, MAIN_COLOUR) => EDGE_COLOUR_CODE,
            (EDGE_COLOUR_CODE, c) => direct_colour(self.edge(c).unwrap_or(DEFAULT_EDGE_RGB)),
            (c, _) => c,
        }
    }

    /// Name of a code, if known.
    pub fn name(&self, code: i32) -> Option<&str> {
        self.map.get(&code).map(|(n, _)| n.as_str())
    }

    /// Codes in the table, sorted.
    pub fn codes(&self) -> Vec<i32> {
        let mut c: Vec<i32> = self.map.keys().copied().collect();
        c.sort_unstable();
        c
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn builtin_direct_and_unknown() {
        let t = ColourTable::builtin();
        assert_eq!(t.rgb(4), [0xB4, 0, 0]);
        assert_eq!(t.name(71), Some("Light_Bluish_Grey"));
        assert_eq!(t.rgb(0x2FF8000), [0xFF, 0x80, 0x00]);
        assert_eq!(t.rgb(99999), UNKNOWN_RGB);
    }

    #[test]
    fn ldconfig_lines_override() {
        let t = ColourTable::with_ldconfig(
            "0 !COLOUR Red CODE 4 VALUE #FF0000 EDGE #333333\n0 !COLOUR New CODE 9999 VALUE #010203 EDGE #000\nnot a colour",
        );
        assert_eq!(t.rgb(4), [255, 0, 0]);
        assert_eq!(t.rgb(9999), [1, 2, 3]);
    }
}
