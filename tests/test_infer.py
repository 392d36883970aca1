"""python -m mepnet.infer: the demo path (bundled example) and its error handling."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
from conftest import generate_manuals
from PIL import Image


def run(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "mepnet.infer", *args], capture_output=True, text=True, timeout=300
    )


def test_demo_prints_the_plan_and_renders_steps(tmp_path: Path):
    r = run("--out", str(tmp_path / "out"), "--size", "96")
    assert r.returncode == 0, r.stderr
    # submodules first, then the main model
    assert r.stdout.index("tower.ldr (submodule") < r.stdout.index("house.ldr (main model")
    assert "8 of 8 steps checked: 8 valid" in r.stdout
    images = sorted((tmp_path / "out").glob("*.png"))
    assert len(images) == 8
    first = np.asarray(Image.open(images[0]))
    assert first.shape == (96, 96, 3)
    # something was drawn on the white background
    assert (first.reshape(-1, 3) != 255).any(axis=1).sum() > 200


def test_bad_model_exits_2(tmp_path: Path):
    bad = tmp_path / "bad.ldr"
    bad.write_text("1 4 0 0 0 1 0 0 0 1\n")
    r = run(str(bad))
    assert r.returncode == 2
    assert "Traceback" not in r.stderr and "bad.ldr:1" in r.stderr


def test_manual_folder_to_plan_files(tmp_path: Path):
    import json

    from mepnet import ldraw

    data = generate_manuals(tmp_path / "data", 1, 31, size=96)
    manual = data / "manual_00000031"
    out = tmp_path / "plan"
    r = run(str(manual), "--predictor", "oracle", "--out", str(out))
    assert r.returncode == 0, r.stderr
    plan = json.loads((out / "plan.json").read_text())
    assert plan["schema"] == "mepnet.plan" and plan["correct"] == plan["components"] > 0
    first = plan["steps"][0]["components"][0]
    assert {"component", "yaw", "lattice", "ldu", "attach", "confidence"} <= set(first)
    # plan.mpd opens with our reader, holds every part, and every step is physically valid
    info = ldraw.inspect(ldraw.read(out / "plan.mpd"))
    assert info["steps_checked"] == info["steps_valid"] > 0
    assert len(list(out.glob("*overlay_*.png"))) == len(plan["steps"]) + sum(
        len(s["steps"]) for s in plan["submodules"]
    )
    assert "components exactly right (100.0%)" in r.stdout
    # the detector needs weights until trained ones ship
    r = run(str(manual), "--out", str(tmp_path / "p2"))
    assert r.returncode == 2 and "--weights" in r.stderr and "Traceback" not in r.stderr
