"""python -m mepnet.ldraw to-manual: real models as manual folders."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from mepnet import ldraw
from mepnet.ldraw.convert import convert
from mepnet.manual import load_manual

SHARED = Path(__file__).resolve().parents[2] / "shared"
REAL = SHARED / "real" / "models"
LDRAW_ROOT = SHARED / "ldraw"
needs_shared = pytest.mark.skipif(
    not (REAL.is_dir() and LDRAW_ROOT.is_dir()),
    reason=f"real models / LDraw library not found under {SHARED} (../shared beside the clone)",
)

TWO_MODELS = b"""0 FILE main.ldr
1 4 0 -8 0 1 0 0 0 1 0 0 0 1 3020.dat
0 STEP
1 16 0 -32 0 1 0 0 0 1 0 0 0 1 tower.ldr
1 14 40 -32 0 1 0 0 0 1 0 0 0 1 99999.dat
0 STEP
0 NOFILE
0 FILE tower.ldr
1 1 0 0 0 1 0 0 0 1 0 0 0 1 3003.dat
0 STEP
1 15 0 -24 0 1 0 0 0 1 0 0 0 1 3003.dat
0 STEP
0 NOFILE
"""


def test_small_model_without_ldraw_library(tmp_path: Path):
    f = ldraw.parse(TWO_MODELS, "two.mpd")
    out = tmp_path / "m"
    report = convert(f, out, ldraw_dir=None, size=64)
    assert report["steps"] == 4 and report["submodules"] == 1
    assert report["dropped"] == 1 and report["substituted"] == 0
    m = load_manual(out)
    assert m.source["kind"] == "ldraw"
    assert (
        m.source["dropped"][0]["name"] == "99999.dat"
        and "--ldraw-dir" in m.source["dropped"][0]["reason"]
    )
    sub = m.submodules[0]
    assert sub.name == "tower.ldr" and len(sub.steps) == 2
    assert len(m.answers.submodules[0].steps) == 2 and m.answers.shapes[0].name == "tower.ldr"
    # the main model's second step places the submodule on the plate
    step = m.main.steps[1]
    assert step.components[0].component.submodule == 0
    assert m.answers.build(None).steps[1].views[0].attach == "on_studs"
    assert len(m.main.steps[0].image().shape) == 3


@needs_shared
def test_every_real_model_converts(tmp_path: Path):
    files = sorted(REAL.glob("*.mpd"))
    assert len(files) == 35
    total_steps = 0
    for k, path in enumerate(files):
        out = tmp_path / f"m{k}"
        r = subprocess.run(
            [
                sys.executable,
                "-m",
                "mepnet.ldraw",
                "to-manual",
                str(path),
                "--out",
                str(out),
                "--ldraw-dir",
                str(LDRAW_ROOT),
                "--size",
                "64",
            ],
            capture_output=True,
            text=True,
            timeout=300,
        )
        assert r.returncode == 0, f"{path.name}: {r.stderr}"
        m = load_manual(out)
        doc = json.loads((out / "manual.json").read_text())
        report = doc["source"]["report"]
        assert report["parts_kept"] > 0 and len(m.main.steps) > 0
        # every substitution and drop is recorded with its reason and the line it comes from
        assert all("replaced_by" in s for s in doc["source"]["substitutions"])
        assert all(d["reason"] and d["line"] > 0 for d in doc["source"]["dropped"])
        total_steps += report["steps"]
        ids = m.answers.main.steps[-1].ids()
        assert (ids >= 0).any()
    assert total_steps > 500


@needs_shared
def test_to_manual_refuses_to_overwrite(tmp_path: Path):
    out = tmp_path / "exists"
    out.mkdir()
    r = subprocess.run(
        [
            sys.executable,
            "-m",
            "mepnet.ldraw",
            "to-manual",
            str(next(REAL.glob("*.mpd"))),
            "--out",
            str(out),
        ],
        capture_output=True,
        text=True,
    )
    assert r.returncode == 2 and "already exists" in r.stderr and "Traceback" not in r.stderr


@needs_shared
def test_substitution_keeps_the_footprint(tmp_path: Path):
    # 4070 (brick 1x1 with headlight) stands in as 3005 (brick 1x1) in the truck
    f = ldraw.read(REAL / "10156-1 - LEGO Truck.mpd")
    convert(f, tmp_path / "t", ldraw_dir=str(LDRAW_ROOT), size=64)
    doc = json.loads((tmp_path / "t" / "manual.json").read_text())
    subs = {s["name"]: s["replaced_by"] for s in doc["source"]["substitutions"]}
    assert subs.get("4070.dat") == "3005"
    # the substitute's body covers the original's body (same world bounds within 2 LDU)
    from mepnet.ldraw.convert import Substitutes, library_box

    finder = Substitutes(str(LDRAW_ROOT))
    ref = next(r for m in f.models for st in m.steps for r in st if r.name == "4070.dat")
    yaw, t, off, non_yaw = ldraw.lattice_pose(ref.position, ref.matrix)
    assert not off and not non_yaw
    (part, yaw2, t2), _ = finder.find("4070", yaw, t)
    assert part == "3005"

    def world_bounds(box, yaw, t):
        corners = np.array(
            [
                [x, y, z]
                for x in (box.lo[0], box.hi[0])
                for y in (box.lo[1], box.hi[1])
                for z in (box.lo[2], box.hi[2])
            ]
        )
        rot = [
            lambda p: p,
            lambda p: (p[2], p[1], -p[0]),
            lambda p: (-p[0], p[1], -p[2]),
            lambda p: (-p[2], p[1], p[0]),
        ][yaw]
        w = np.array([rot(c) for c in corners]) + np.array(t) * [10.0, 8.0, 10.0]
        return w.min(axis=0), w.max(axis=0)

    original = world_bounds(finder.measure("4070")[0], yaw, t)
    substitute = world_bounds(library_box("3005"), yaw2, t2)
    assert np.allclose(original[0], substitute[0], atol=2.0) and np.allclose(
        original[1], substitute[1], atol=2.0
    )


# -- colours: LDraw's inheritance (16 = the colour of the reference placing the model) --------

TWO_COLOURS = b"""0 FILE main.ldr
1 4 0 -8 0 1 0 0 0 1 0 0 0 1 3020.dat
1 4 0 -8 40 1 0 0 0 1 0 0 0 1 3020.dat
0 STEP
1 14 -20 -32 0 1 0 0 0 1 0 0 0 1 tower.ldr
1 1 20 -32 0 1 0 0 0 1 0 0 0 1 tower.ldr
0 STEP
1 2 -20 -32 40 1 0 0 0 1 0 0 0 1 fixed.ldr
1 5 20 -32 40 1 0 0 0 1 0 0 0 1 fixed.ldr
0 STEP
0 NOFILE
0 FILE tower.ldr
1 16 0 0 0 1 0 0 0 1 0 0 0 1 3003.dat
0 STEP
1 15 0 -24 0 1 0 0 0 1 0 0 0 1 3003.dat
0 STEP
0 NOFILE
0 FILE fixed.ldr
1 0 0 0 0 1 0 0 0 1 0 0 0 1 3003.dat
0 NOFILE
"""


def test_submodel_in_two_colours_is_built_in_each(tmp_path: Path):
    report = convert(ldraw.parse(TWO_COLOURS, "two.mpd"), tmp_path / "m", size=64)
    m = load_manual(tmp_path / "m")
    names = [s.name for s in m.submodules]
    # tower inherits its colour: one submodule per colour; fixed does not: one submodule
    assert sorted(names) == ["fixed.ldr", "tower (colour 1).ldr", "tower (colour 14).ldr"]
    assert report["submodules"] == 3 and report["dropped"] == 0
    for k, name in enumerate(names):
        own = [i.colour for i in m.answers.submodules[k].instances]
        bricks = [b[3] for b in m.answers.shapes[k].bricks]
        want = {"fixed.ldr": [0], "tower (colour 1).ldr": [1, 15]}.get(name, [14, 15])
        # its own build (pictures, callouts) and its bricks show the real colours
        assert own == want and bricks == want, name
        callout = sorted(c.colour for s in m.submodules[k].steps for c in s.components)
        assert callout == sorted(want), name
    placed = {
        names[i.component.submodule]: i.colour
        for i in m.answers.main.instances
        if i.component.submodule is not None
    }
    assert placed["tower (colour 14).ldr"] == 14 and placed["tower (colour 1).ldr"] == 1


WRAPPED = b"""0 FILE main.ldr
1 14 0 0 0 1 0 0 0 1 0 0 0 1 model.ldr
0 NOFILE
0 FILE model.ldr
1 16 0 0 0 1 0 0 0 1 0 0 0 1 3020.dat
0 STEP
1 4 -20 -24 0 1 0 0 0 1 0 0 0 1 3003.dat
1 16 20 -24 0 1 0 0 0 1 0 0 0 1 3003.dat
0 NOFILE
"""


def test_wrapped_model_takes_the_wrappers_colour(tmp_path: Path):
    report = convert(ldraw.parse(WRAPPED, "w.mpd"), tmp_path / "m", size=64)
    assert report["main_model"] == "model.ldr"
    m = load_manual(tmp_path / "m")
    assert [i.colour for i in m.answers.main.instances] == [14, 4, 14]
    callouts = [(c.component.part, c.colour, c.count) for s in m.main.steps for c in s.components]
    assert callouts == [("3020", 14, 1), ("3003", 4, 1), ("3003", 14, 1)]


def _real_colours(text: str) -> dict[tuple[str, int], list[int]]:
    """LDraw's colour inheritance resolved from the raw text, independently of mepnet: per
    (model name lower-cased, line number) of a type-1 line, the colours it shows in the model
    (one per path from the main model). Only 16 is resolved: the real files use no 24 on
    type-1 lines (asserted)."""
    models: dict[str, list[tuple[int, int, str]]] = {}
    order: list[str] = []
    current = None
    for n, line in enumerate(text.splitlines(), start=1):
        f = line.split()
        if len(f) >= 3 and f[0] == "0" and f[1] == "FILE":
            current = line.split(None, 2)[2].strip().lower()
            models[current] = []
            order.append(current)
        elif f and f[0] == "1" and current is not None:
            name = " ".join(line.split(None, 14)[14:]).strip().lower()
            assert int(f[1]) != 24
            models[current].append((n, int(f[1]), name))
    out: dict[tuple[str, int], list[int]] = {}
    stack = [(order[0], 16)]  # the main model: nothing places it
    while stack:
        model, inherited = stack.pop()
        for n, colour, name in models[model]:
            real = inherited if colour == 16 else colour
            out.setdefault((model, n), []).append(real)
            if name in models:
                stack.append((name, real))
    return out


@needs_shared
def test_real_colours_of_the_truck(tmp_path: Path):
    """10156 LEGO Truck: the main model places the truck (tilted) in yellow, and most of the
    truck's lines say 16. The converted manual shows them yellow, in the answers and in the
    callouts, as the raw file says."""
    path = REAL / "10156-1 - LEGO Truck.mpd"
    real = _real_colours(path.read_text(encoding="utf-8", errors="replace"))
    report = convert(ldraw.read(path), tmp_path / "t", ldraw_dir=str(LDRAW_ROOT), size=64)
    truck = report["main_model"].lower()
    assert truck == "10156 - truck.ldr"
    m = load_manual(tmp_path / "t")
    assert not m.submodules  # the truck places parts only: each kept line is one instance
    dropped = [d for d in m.source["dropped"] if d["model"].lower() == truck]
    assert all("line" in d for d in dropped)
    gone = {d["line"] for d in dropped}
    kept = [c for (model, n), cs in real.items() if model == truck and n not in gone for c in cs]
    shown = [i.colour for i in m.answers.main.instances]
    assert sorted(shown) == sorted(kept)
    yellow = kept.count(14)
    assert yellow >= 20 and shown.count(14) == yellow and 16 not in shown
    callout: dict[int, int] = {}
    for s in m.main.steps:
        for c in s.components:
            callout[c.colour] = callout.get(c.colour, 0) + c.count
    assert callout.get(14) == yellow and 16 not in callout
