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
        # every substitution and drop is recorded with its reason
        assert all("replaced_by" in s for s in doc["source"]["substitutions"])
        assert all(d["reason"] for d in doc["source"]["dropped"])
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
