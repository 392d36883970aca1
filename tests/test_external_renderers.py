"""The held-out renderers' redraws (tests/external/): POV-Ray draws a generated manual from its
stated cameras where mepnet draws it, with the same handedness. Skipped where POV-Ray or the
shared LDraw library is missing (CI has neither POV-Ray nor a display)."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import generate_manuals

ROOT = Path(__file__).resolve().parents[1]
LDRAW_ROOT = ROOT.parent / "shared" / "ldraw"


@pytest.mark.skipif(shutil.which("povray") is None, reason="POV-Ray is not installed")
@pytest.mark.skipif(not (LDRAW_ROOT / "parts").is_dir(), reason="../shared/ldraw is absent")
def test_povray_draws_each_step_where_mepnet_does(tmp_path: Path):
    data = generate_manuals(tmp_path / "in", 1, 4242, size=128)
    out = tmp_path / "out"
    cmd = [sys.executable, str(ROOT / "tests/external/povray_manuals.py"), "--data", str(data)]
    r = subprocess.run([*cmd, "--out", str(out), "--workers", "2", "--ldraw", str(LDRAW_ROOT)],
                       capture_output=True, text=True, timeout=900)  # fmt: skip
    assert r.returncode == 0, r.stdout + r.stderr
    report = json.loads((out / "povray_report.json").read_text())
    s = report["summary"]
    assert s["failed"] == 0 and s["iou"]["median"] > 0.95
    assert s["iou_mirrored"]["median"] < s["iou"]["median"] - 0.1  # not a mirror image
    assert abs(s["scale"]["median"] - 1) < 0.02  # the camera is set exactly, not found
    (src,) = [p for p in data.iterdir() if p.is_dir()]
    for row in report["steps"]:
        new, old = out / src.name / row["image"], src / row["image"]
        assert new.read_bytes() != old.read_bytes()  # every picture redrawn
    # an existing output folder is never touched; bad input is one line, exit 2
    again = subprocess.run([*cmd, "--out", str(out)], capture_output=True, text=True)
    assert again.returncode == 2 and again.stderr.count("\n") == 1 and "exists" in again.stderr
