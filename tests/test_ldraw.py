"""mepnet.ldraw: typed reading/writing, inspection, the CLI and its bad-input behaviour."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import mepnet
import pytest
from mepnet import ldraw
from mepnet.ldraw.io import IDENTITY

REAL = Path(__file__).resolve().parents[2] / "shared" / "real" / "models"
LDRAW_ROOT = Path(__file__).resolve().parents[2] / "shared" / "ldraw"
needs_real = pytest.mark.skipif(
    not REAL.is_dir(), reason=f"real models not found at {REAL} (../shared beside the clone)"
)
needs_ldraw = pytest.mark.skipif(
    not LDRAW_ROOT.is_dir(), reason=f"LDraw library not found at {LDRAW_ROOT}"
)

SMALL = b"""0 FILE main.ldr
0 test model
1 4 0 -24 0 1 0 0 0 1 0 0 0 1 3001.dat
0 STEP
1 16 0 -48 0 0 0 1 0 1 0 -1 0 0 sub.ldr
0 STEP
0 NOFILE
0 FILE sub.ldr
1 1 0 0 0 1 0 0 0 1 0 0 0 1 3003.dat
0 NOFILE
"""


def run_cli(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "mepnet.ldraw", *args], capture_output=True, text=True, timeout=120
    )


def test_parse_gives_typed_tree():
    f = ldraw.parse(SMALL, "small.mpd")
    assert [m.name for m in f.models] == ["main.ldr", "sub.ldr"]
    assert len(f.main.steps) == 2
    ref = f.main.steps[1][0]
    assert ref.is_submodel and ref.name == "sub.ldr" and ref.line == 5
    assert ref.matrix[0] == (0.0, 0.0, 1.0)
    assert f.model("SUB.LDR") is f.models[1]
    flat = f.flatten()
    assert [p.name for p in flat] == ["3001.dat", "3003.dat"]
    assert flat[1].colour == 1 and flat[1].step == 1 and flat[1].path == ("sub.ldr",)


def test_write_read_round_trip(tmp_path: Path):
    f = ldraw.parse(SMALL, "small.mpd")
    out = tmp_path / "out.mpd"
    ldraw.write(out, f)
    assert ldraw.read(out) == ldraw.LDrawFile(name="out.mpd", models=f.models, embedded_parts=[])
    assert "0 STEP" in out.read_text()


def test_binding_types_are_frozen_and_typed():
    f = ldraw.parse(SMALL, "small.mpd")
    assert type(f) is ldraw.LDrawFile is mepnet._brickgeom.LDrawFile
    assert isinstance(f.models, tuple) and all(type(m) is ldraw.LDrawModel for m in f.models)
    ref = f.main.steps[0][0]
    assert type(ref) is ldraw.LDrawRef and isinstance(f.main.steps[0], tuple)
    assert type(ref.position) is tuple and type(ref.matrix[0]) is tuple
    assert type(ref.position[0]) is float and type(ref.colour) is int
    # repeated access gives the same objects (made once)
    assert f.models is f.models and f.main.steps is f.main.steps and f.main is f.models[0]
    for obj, attr, value in [
        (f, "name", "x.mpd"),
        (f, "models", ()),
        (f.main, "steps", ()),
        (f.main, "title", "x"),
        (ref, "name", "3002.dat"),
        (ref, "position", (0.0, 0.0, 0.0)),
        (ref, "line", 1),
    ]:
        with pytest.raises(AttributeError, match="not writable"):
            setattr(obj, attr, value)
    assert "3001.dat" in repr(ref) and "main.ldr" in repr(f.main) and "small.mpd" in repr(f)
    flat = f.flatten()
    assert all(type(p) is ldraw.FlatPart for p in flat) and flat == f.flatten()
    assert f.to_text() == mepnet._brickgeom.format_ldraw(f)

    checks = ldraw.check(f)
    assert [type(m) for m in checks] == [ldraw.ModelCheck] * 2
    main = checks[0]
    assert main.name == "main.ldr" and main.placeable and main.offset == (0.0, 0.0, 0.0)
    assert [type(s) for s in main.steps] == [ldraw.StepCheck] * 2
    step = main.steps[0]
    assert (step.step, step.items, step.placeable, step.complete_base) == (1, 1, 1, True)
    assert step.results == ((True, "ground"),)
    brick, sub = main.items[0][0], main.items[1][0]
    assert type(brick) is ldraw.StepItem
    assert (brick.kind, brick.part, brick.submodel, brick.yaw, brick.t) == (
        "part",
        "3001",
        None,
        0,
        (0, 3, 0),
    )
    assert (sub.kind, sub.part, sub.submodel, sub.line, sub.blocker) == (
        "submodel",
        None,
        1,
        5,
        None,
    )
    assert ldraw.build_order(checks) == [1, 0]
    with pytest.raises(AttributeError):
        step.results = None  # type: ignore[misc]


def test_binding_equality_ignores_line_and_builds_from_python():
    f = ldraw.parse(SMALL, "small.mpd")
    ref = f.main.steps[0][0]
    same = ldraw.LDrawRef("3001.dat", 4, [0, -24, 0], IDENTITY, line=99)
    assert ref == same and hash(ref) == hash(same) and ref != ldraw.LDrawRef("3001.dat", 4)
    assert ref != "3001.dat"
    built = ldraw.LDrawFile(
        "small.mpd",
        [
            ldraw.LDrawModel("main.ldr", [[same], [f.main.steps[1][0]]], title="test model"),
            ldraw.LDrawModel("sub.ldr", f.models[1].steps),
        ],
    )
    assert built == f and built.models[0].steps[0][0] is same
    assert built != ldraw.LDrawFile("other.mpd", f.models)
    with pytest.raises(TypeError, match="unhashable"):
        hash(f)


@pytest.mark.parametrize(
    "build, error, message",
    [
        (lambda: ldraw.LDrawRef(""), mepnet.LDrawError, "name is empty"),
        (lambda: ldraw.LDrawRef("a.dat", position=(0, float("nan"), 0)), mepnet.LDrawError, "NaN"),
        (lambda: ldraw.LDrawRef("a.dat", position=(2e6, 0, 0)), mepnet.LDrawError, "within"),
        (lambda: ldraw.LDrawRef("a.dat", matrix=((1, 0, 0),) * 3), mepnet.LDrawError, "singular"),
        (lambda: ldraw.LDrawRef("a.dat", position=(0, 0)), ValueError, "length 3"),
        (lambda: ldraw.LDrawRef("a.dat", matrix=((1, 0, 0),)), ValueError, "length 3"),
        (
            lambda: ldraw.LDrawModel(" ", [[ldraw.LDrawRef("a.dat")]]),
            mepnet.LDrawError,
            "name is empty",
        ),
        (lambda: ldraw.LDrawModel("m", [[]]), mepnet.LDrawError, "step 1 is empty"),
        (lambda: ldraw.LDrawModel("m", [[{"name": "a.dat"}]]), TypeError, "LDrawRef"),
        (
            lambda: ldraw.LDrawFile("f.mpd", [], [("", "2 24 0 0 0 1 1 1")]),
            mepnet.LDrawError,
            "embedded part",
        ),
        (lambda: ldraw.LDrawFile("f.mpd").main, IndexError, "no models"),
    ],
)
def test_binding_rejects_bad_constructor_input(build, error, message):
    with pytest.raises(error, match=message):
        build()


def test_pose_conversion_inverts():
    for yaw in range(4):
        pos, mat = ldraw.ldraw_placement(yaw, (3, 5, -7))
        assert ldraw.lattice_pose(tuple(pos), tuple(tuple(r) for r in mat)) == (
            yaw,
            (3, 5, -7),
            False,
            False,
        )
    assert ldraw.lattice_pose((5.0, 0.0, 0.0), IDENTITY)[2] is True  # half a half-stud off


@pytest.mark.parametrize(
    "text, message",
    [
        (b"1 4 0 0 0 1 0 0 0 1 0 0 0 1\n", r"bad\.ldr:1"),
        (b"1 4 0 zero 0 1 0 0 0 1 0 0 0 1 3001.dat\n", r"bad\.ldr:1"),
        (b"0 ok\n1 4 0 0 0 0 0 0 0 0 0 0 0 0 3001.dat\n", r"bad\.ldr:2.*singular"),
        (b"1 4 1e300 0 0 1 0 0 0 1 0 0 0 1 3001.dat\n", r"bad\.ldr:1"),
        (b"", r"bad\.ldr.*empty"),
        (b"\x00\x01\x02binary", r"bad\.ldr.*binary"),
        (b"1 4 0 0 0 1 0 0 0 1 0 0 0 1 other.ldr\n", r"bad\.ldr:1.*missing"),
    ],
)
def test_malformed_input_is_a_typed_error(text: bytes, message: str):
    with pytest.raises(mepnet.LDrawError, match=message):
        ldraw.parse(text, "bad.ldr")


def test_cyclic_submodels_are_rejected():
    text = b"0 FILE a.ldr\n1 4 0 0 0 1 0 0 0 1 0 0 0 1 b.ldr\n0 FILE b.ldr\n1 4 0 0 0 1 0 0 0 1 0 0 0 1 a.ldr\n"
    with pytest.raises(mepnet.LDrawError, match="cyclic"):
        ldraw.parse(text, "cycle.mpd")


def test_write_to_missing_folder_fails_cleanly(tmp_path: Path):
    f = ldraw.parse(SMALL, "small.mpd")
    target = tmp_path / "no" / "such" / "dir" / "x.mpd"
    with pytest.raises(mepnet.FileError):
        ldraw.write(target, f)
    assert not target.parent.exists()


def test_inspect_reports_validity_of_the_bundled_example():
    from mepnet.infer import bundled_example

    info = ldraw.inspect(ldraw.read(bundled_example()))
    assert info["known_parts"] == info["parts"] == 12
    assert info["steps_checked"] == info["steps_valid"] == 8


def test_inspect_finds_an_invalid_step():
    # the second brick floats one plate above the first: not connected
    text = (
        b"1 4 0 -24 0 1 0 0 0 1 0 0 0 1 3001.dat\n0 STEP\n1 4 0 -56 0 1 0 0 0 1 0 0 0 1 3001.dat\n"
    )
    info = ldraw.inspect(ldraw.parse(text, "float.ldr"))
    assert info["steps_checked"] == 2 and info["steps_valid"] == 1 and info["steps_invalid"] == 1


def test_cli_info_ok(tmp_path: Path):
    p = tmp_path / "small.mpd"
    p.write_bytes(SMALL)
    r = run_cli("info", str(p), "--steps", "--json", str(tmp_path / "info.json"))
    assert r.returncode == 0, r.stderr
    assert "library coverage: 2/2 parts" in r.stdout
    assert (tmp_path / "info.json").exists()


def test_cli_bad_input_exits_2_with_one_line(tmp_path: Path):
    p = tmp_path / "broken.ldr"
    p.write_bytes(b"1 4 0 0 0 1 0 0 0 1 0 0 0\n")
    for target in (str(p), str(tmp_path / "missing.ldr")):
        r = run_cli("info", target)
        assert r.returncode == 2
        assert "Traceback" not in r.stderr
        assert len(r.stderr.strip().splitlines()) == 1
        assert Path(target).name in r.stderr


@needs_real
def test_every_real_model_loads_and_round_trips(tmp_path: Path):
    files = sorted(REAL.glob("*.mpd"))
    assert len(files) == 35
    for f in files:
        model = ldraw.read(f)
        info = ldraw.inspect(model)
        assert info["parts"] > 0 and info["steps"] > 0
        out = tmp_path / "rt.mpd"
        ldraw.write(out, model)
        back = ldraw.read(out)
        assert back.models == model.models, f.name


@needs_ldraw
def test_real_part_geometry_loads():
    v, t, studs = ldraw.load_part_mesh(LDRAW_ROOT, "3001")
    assert studs == 8
    assert v.min(axis=0)[1] == pytest.approx(-24.0) and v.max(axis=0)[1] == pytest.approx(4.0)
    assert t.max() < len(v)
    with pytest.raises(mepnet.LDrawError, match="no-such-part"):
        ldraw.load_part_mesh(LDRAW_ROOT, "no-such-part")
