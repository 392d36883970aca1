//! LDraw colour inheritance: 16 is the colour of the reference placing the file (through any
//! depth of submodels, 16 at the top level), 24 that colour's edge colour, direct colours
//! `0x2RRGGBB` pass through. Flattening (top-down) and the lattice resolution of submodels
//! (bottom-up: a submodel's bricks, then the reference placing them) must agree.

use brickgeom::colours::{direct_colour, resolve_colour, ColourTable, DEFAULT_EDGE_RGB};
use brickgeom::component::Brick;
use brickgeom::ldraw::parse_ldraw;
use brickgeom::realmodel::LatticeFile;
use brickgeom::Pose;

/// Edge colour of Red (4) and of Black (0) in LDConfig.ldr, as direct colours.
const EDGE_RED: i32 = 0x233_3333;
const EDGE_BLACK: i32 = 0x280_8080;

/// `(name, colour)` of every flattened part, in file order.
fn flat(text: &str) -> Vec<(String, i32)> {
    let file = parse_ldraw(text.as_bytes(), "t.mpd").unwrap();
    file.flatten()
        .into_iter()
        .map(|p| (p.name, p.colour))
        .collect()
}

/// `(part, colour)` of the bricks of model `m` resolved on the lattice, sorted.
fn bricks(text: &str, m: usize) -> Vec<(&'static str, i32)> {
    let file = parse_ldraw(text.as_bytes(), "t.mpd").unwrap();
    let lf = LatticeFile::new(&file);
    let mut out: Vec<_> = lf
        .bricks(m)
        .unwrap_or_else(|| panic!("model {m} is placeable"))
        .iter()
        .map(|b| (b.part, b.colour))
        .collect();
    out.sort();
    out
}

/// The flattened colours as library ids (3001.dat -> 3001), sorted: comparable with `bricks`.
fn flat_sorted(text: &str) -> Vec<(&'static str, i32)> {
    let mut out: Vec<_> = flat(text)
        .into_iter()
        .map(|(n, c)| {
            let id = brickgeom::library().resolve(&n).unwrap();
            (id, c)
        })
        .collect();
    out.sort();
    out
}

/// main -(14)-> a -(16)-> b -(16 and 4)-> c: 16 resolves through three levels of submodels.
const NESTED: &str = "0 FILE main.ldr
1 14 0 0 0 1 0 0 0 1 0 0 0 1 a.ldr
1 16 100 0 0 1 0 0 0 1 0 0 0 1 3001.dat
0 FILE a.ldr
1 16 0 -24 0 1 0 0 0 1 0 0 0 1 b.ldr
1 2 0 -96 0 1 0 0 0 1 0 0 0 1 3003.dat
0 FILE b.ldr
1 16 0 -24 0 1 0 0 0 1 0 0 0 1 c.ldr
1 4 60 -24 0 1 0 0 0 1 0 0 0 1 c.ldr
0 FILE c.ldr
1 16 0 0 0 1 0 0 0 1 0 0 0 1 3001.dat
1 1 0 -24 0 1 0 0 0 1 0 0 0 1 3003.dat
";

#[test]
fn main_colour_resolves_through_three_levels() {
    let names = |v: Vec<(String, i32)>| v.into_iter().map(|(_, c)| c).collect::<Vec<_>>();
    // c through b (16) through a (16) from main (14); c placed in 4; a's own part; main's own
    // part: 16 at the top level stays 16
    assert_eq!(names(flat(NESTED)), vec![14, 1, 4, 1, 2, 16]);
}

#[test]
fn lattice_bricks_resolve_like_flattening() {
    assert_eq!(
        bricks(NESTED, 0),
        vec![
            ("3001", 4),
            ("3001", 14),
            ("3001", 16),
            ("3003", 1),
            ("3003", 1),
            ("3003", 2)
        ]
    );
    assert_eq!(bricks(NESTED, 0), flat_sorted(NESTED));
    // a submodel's own bricks keep 16 where nothing inside it sets a colour: the reference
    // placing it decides
    assert_eq!(
        bricks(NESTED, 1),
        vec![
            ("3001", 4),
            ("3001", 16),
            ("3003", 1),
            ("3003", 1),
            ("3003", 2)
        ]
    );
    // ... and placing it resolves them (Brick::placed_by, as an assembly does)
    let file = parse_ldraw(NESTED.as_bytes(), "t.mpd").unwrap();
    let lf = LatticeFile::new(&file);
    let mut placed: Vec<i32> = lf
        .bricks(1)
        .unwrap()
        .iter()
        .map(|b| b.placed_by(&Pose::new(0, [0, 0, 0]), 14).colour)
        .collect();
    placed.sort();
    assert_eq!(placed, vec![1, 1, 2, 4, 14]);
}

/// One submodel placed twice in two colours, and once in the main colour.
const TWICE: &str = "0 FILE main.ldr
1 4 0 0 0 1 0 0 0 1 0 0 0 1 w.ldr
1 1 100 0 0 1 0 0 0 1 0 0 0 1 w.ldr
1 16 200 0 0 1 0 0 0 1 0 0 0 1 w.ldr
0 FILE w.ldr
1 16 0 0 0 1 0 0 0 1 0 0 0 1 3020.dat
1 15 0 -8 0 1 0 0 0 1 0 0 0 1 3003.dat
";

#[test]
fn submodel_referenced_in_two_colours() {
    let colours: Vec<i32> = flat(TWICE).into_iter().map(|(_, c)| c).collect();
    assert_eq!(colours, vec![4, 15, 1, 15, 16, 15]);
    assert_eq!(bricks(TWICE, 0), flat_sorted(TWICE));
    assert_eq!(bricks(TWICE, 1), vec![("3003", 15), ("3020", 16)]);
}

/// 24 on type-1 lines: the edge colour of the inherited colour.
const EDGES: &str = "0 FILE main.ldr
1 24 0 0 0 1 0 0 0 1 0 0 0 1 3001.dat
1 4 100 0 0 1 0 0 0 1 0 0 0 1 e.ldr
1 0 200 0 0 1 0 0 0 1 0 0 0 1 e.ldr
1 16 300 0 0 1 0 0 0 1 0 0 0 1 f.ldr
1 0 400 0 0 1 0 0 0 1 0 0 0 1 f.ldr
0 FILE e.ldr
1 24 0 0 0 1 0 0 0 1 0 0 0 1 3001.dat
1 16 0 -24 0 1 0 0 0 1 0 0 0 1 3003.dat
0 FILE f.ldr
1 24 0 0 0 1 0 0 0 1 0 0 0 1 e.ldr
";

#[test]
fn edge_colour_is_the_inherited_colours_edge() {
    let colours: Vec<i32> = flat(EDGES).into_iter().map(|(_, c)| c).collect();
    let edge_of_edge = direct_colour(DEFAULT_EDGE_RGB);
    assert_eq!(
        colours,
        vec![
            24, // top level: nothing sets a colour, 24 stays 24
            EDGE_RED,
            4,
            EDGE_BLACK,
            0,
            // f in 16: e in 24 (still unresolved); its 24 is the edge of an edge colour
            edge_of_edge,
            24,
            // f in black: e in black's edge colour (a direct colour: default edge)
            edge_of_edge,
            EDGE_BLACK,
        ]
    );
    // bottom-up resolution on the lattice agrees, although f's bricks were resolved
    // before f's reference colour was known
    assert_eq!(bricks(EDGES, 0), flat_sorted(EDGES));
}

/// Direct colours pass through, and are inherited like any colour.
const DIRECT: &str = "0 FILE main.ldr
1 33554432 0 0 0 1 0 0 0 1 0 0 0 1 3001.dat
1 35799648 100 0 0 1 0 0 0 1 0 0 0 1 d.ldr
0 FILE d.ldr
1 16 0 0 0 1 0 0 0 1 0 0 0 1 3001.dat
1 24 0 -24 0 1 0 0 0 1 0 0 0 1 3001.dat
1 41943040 0 -48 0 1 0 0 0 1 0 0 0 1 3003.dat
";

#[test]
fn direct_colours_pass_through() {
    let colours: Vec<i32> = flat(DIRECT).into_iter().map(|(_, c)| c).collect();
    // 0x2000000 (black, direct); in d (placed in 0x2224260): 16 takes it, 24 is the default
    // edge (the table knows no edge for a direct colour), 0x2800000 is the line's own
    assert_eq!(
        colours,
        vec![
            0x200_0000,
            0x222_4260,
            direct_colour(DEFAULT_EDGE_RGB),
            0x280_0000
        ]
    );
    assert_eq!(bricks(DIRECT, 0), flat_sorted(DIRECT));
}

#[test]
fn resolution_rule() {
    // 16 and 24 at the top level stay
    assert_eq!(resolve_colour(16, 16), 16);
    assert_eq!(resolve_colour(24, 16), 24);
    // 16 takes the inherited colour, whatever it is
    for c in [0, 4, 14, 24, 0x2123456, 99_999] {
        assert_eq!(resolve_colour(16, c), c);
    }
    // 24: the table's edge colour as a direct colour, the default edge otherwise
    assert_eq!(resolve_colour(24, 4), EDGE_RED);
    assert_eq!(resolve_colour(24, 0), EDGE_BLACK);
    assert_eq!(resolve_colour(24, 47), 0x2C9_C9C9); // Trans_Clear
    assert_eq!(resolve_colour(24, 99_999), direct_colour(DEFAULT_EDGE_RGB));
    // other colours are the line's own
    for c in [0, 4, 0x2FF8000] {
        assert_eq!(resolve_colour(c, 14), c);
    }
    // bottom-up and top-down agree for every combination
    let codes = [0, 4, 14, 16, 24, 47, 0x2123456, 99_999];
    for x in codes {
        for a in codes {
            for b in codes {
                assert_eq!(
                    resolve_colour(resolve_colour(x, a), b),
                    resolve_colour(x, resolve_colour(a, b)),
                    "x={x} a={a} b={b}"
                );
            }
        }
    }
}

#[test]
fn ldconfig_edges() {
    let t = ColourTable::with_ldconfig(
        "0 !COLOUR Red CODE 4 VALUE #FF0000 EDGE #112233\n\
         0 !COLOUR Odd CODE 9999 VALUE #010203 EDGE 4\n\
         0 !COLOUR Blue CODE 1 VALUE #0000FF",
    );
    assert_eq!(t.edge(4), Some([0x11, 0x22, 0x33]));
    assert_eq!(t.resolve(24, 4), 0x211_2233);
    // an EDGE given as a code takes that code's value
    assert_eq!(t.edge(9999), Some([0xFF, 0, 0]));
    // no EDGE: no edge known, the default is used
    assert_eq!(t.edge(1), None);
    assert_eq!(t.resolve(24, 1), direct_colour(DEFAULT_EDGE_RGB));
    assert_eq!(ColourTable::builtin().edge(6), Some([0x1E, 0x1E, 0x1E]));
    assert_eq!(ColourTable::builtin().edge(24), None);
}

#[test]
fn placed_brick_in_edge_colour() {
    let b = Brick {
        part: "3001",
        pose: Pose::new(0, [0, 0, 0]),
        colour: 24,
    };
    assert_eq!(b.placed_by(&Pose::new(0, [0, 0, 0]), 4).colour, EDGE_RED);
    assert_eq!(b.placed_by(&Pose::new(0, [0, 0, 0]), 16).colour, 24);
}
