"""`python -m mepnet.restyle`: manuals redrawn in another style, everything else unchanged."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import generate_manuals
from mepnet.manual import load_manual


@pytest.fixture(scope="module")
def manuals(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return generate_manuals(tmp_path_factory.mktemp("rs"), 2, 31, size=96)


def restyle(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "mepnet.restyle", *args],
        capture_output=True,
        text=True,
        timeout=300,
    )


def test_restyled_manuals_keep_their_truth_and_change_their_look(manuals: Path, tmp_path: Path):
    a, b = tmp_path / "a", tmp_path / "b"
    for out in (a, b):
        r = restyle("--data", str(manuals), "--out", str(out), "--seed", "4")
        assert r.returncode == 0, r.stderr
        assert "restyled 2 manual(s)" in r.stdout
    for src in sorted(manuals.iterdir()):
        m0, m1 = load_manual(src), load_manual(a / src.name)
        style = m1.source["restyle"]
        assert style["seed"] == 4 and style["lines"] in ("thick", "faint")
        assert {k: v for k, v in m1.source.items() if k != "restyle"} == m0.source
        a0, a1 = m0.answers.main.steps, m1.answers.main.steps
        for s0, s1, t0, t1 in zip(m0.main.steps, m1.main.steps, a0, a1, strict=True):
            assert s0.camera == s1.camera and s0.components == s1.components
            assert t0.ids_path.read_bytes() == t1.ids_path.read_bytes()
            assert t0.views == t1.views and t0.instances_of == t1.instances_of
            i0, i1 = s0.image().astype(int), s1.image().astype(int)
            assert i0.shape == i1.shape
            assert np.abs(i0 - i1).mean() > 1.0  # the look changed
            # same seed, same bytes
            assert s1.image_path.read_bytes() == (b / src.name / s1.image_path.name).read_bytes()
    # a second run leaves what is there
    r = restyle("--data", str(manuals), "--out", str(a))
    assert r.returncode == 0 and "0 manual(s)" in r.stdout and "2 already there" in r.stdout
    assert not list(a.glob(".tmp-*"))


def test_only_the_page(manuals: Path, tmp_path: Path):
    r = restyle("--data", str(manuals), "--out", str(tmp_path), "--only", "page")
    assert r.returncode == 0, r.stderr
    src = sorted(manuals.iterdir())[0]
    m0, m1 = load_manual(src), load_manual(tmp_path / src.name)
    assert set(m1.source["restyle"]) == {"seed", "strength", "page"}
    s0, s1 = m0.main.steps[-1], m1.main.steps[-1]
    ids = m0.answers.main.steps[-1].ids()
    i0, i1 = s0.image(), s1.image()
    assert np.array_equal(i0[ids >= 0], i1[ids >= 0])
    page = i1[ids < 0]
    assert (page == page[0]).all() and page[0].tolist() != [255, 255, 255]
    assert (
        json.loads((tmp_path / src.name / "manual.json").read_text())["schema"] == "mepnet.manual"
    )


@pytest.mark.parametrize(
    "args, message",
    [
        (["--data", "nowhere"], "not a folder"),
        (["--only", "sepia"], "unknown factor"),
        (["--strength", "5"], "--strength"),
    ],
)
def test_bad_input_exits_2(manuals: Path, tmp_path: Path, args: list[str], message: str):
    base = {"--data": str(manuals), "--out": str(tmp_path / "o")}
    for k, v in zip(args[::2], args[1::2], strict=True):
        base[k] = v
    r = restyle(*[x for kv in base.items() for x in kv])
    assert r.returncode == 2
    assert message in r.stderr and "Traceback" not in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1


def test_a_folder_without_manuals_exits_2(tmp_path: Path):
    (tmp_path / "empty").mkdir()
    r = restyle("--data", str(tmp_path / "empty"), "--out", str(tmp_path / "o"))
    assert r.returncode == 2 and "no manual folders" in r.stderr


def test_restyle_runs_on_a_manual_without_answers(manuals: Path, tmp_path: Path):
    from mepnet.manual import strip_manual

    src = sorted(manuals.iterdir())[0]
    strip_manual(src, tmp_path / "data" / src.name)
    r = restyle(
        "--data", str(tmp_path / "data"), "--out", str(tmp_path / "out"), "--only", "lines,page"
    )
    assert r.returncode == 0, r.stderr
    m0, m1 = load_manual(tmp_path / "data" / src.name), load_manual(tmp_path / "out" / src.name)
    assert m1.answers is None
    changed = sum(
        int((a.image() != b.image()).any())
        for a, b in zip(m0.all_steps(), m1.all_steps(), strict=True)
    )
    assert changed == len(m0.all_steps())  # every picture redrawn


def test_restyle_refuses_a_huge_picture_and_leaves_nothing(manuals: Path, tmp_path: Path):
    import shutil

    from test_manual import png_header_only

    src = sorted(manuals.iterdir())[0]
    data = tmp_path / "data"
    shutil.copytree(src, data / src.name)
    png_header_only(data / src.name / "step_002.png", 20000, 20000)
    r = restyle("--data", str(data), "--out", str(tmp_path / "out"))
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert "step_002.png" in r.stderr and r.stderr.count("\n") == 1
    assert list((tmp_path / "out").iterdir()) == []  # no .tmp- folder left
