"""mepnet.manual: the page apart from the answers, the whole file checked on load, pictures read
whatever their mode, and ``python -m mepnet.manual strip``."""

from __future__ import annotations

import json
import shutil
import struct
import subprocess
import sys
import zlib
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from mepnet.errors import ManualFormatError
from mepnet.manual import answers_of, load_manual, manual_json, strip_manual
from mepnet.manual.images import read_instance_map, read_step_image
from mepnet.plan import run_manual
from mepnet.stage2 import make_predictor
from PIL import Image


def bundled() -> Path:
    from mepnet.infer import bundled_manual

    return bundled_manual()


@pytest.fixture
def v2(tmp_path: Path) -> Path:
    """A copy of the bundled example written as version 2."""
    folder = tmp_path / "m"
    shutil.copytree(bundled(), folder)
    doc = manual_json(load_manual(folder))
    (folder / "manual.json").write_text(json.dumps(doc, indent=1))
    return folder


def edit(folder: Path, change: Any) -> None:
    doc = json.loads((folder / "manual.json").read_text())
    change(doc)
    (folder / "manual.json").write_text(json.dumps(doc))


@pytest.fixture
def v1(tmp_path: Path) -> Path:
    """The bundled example as it was written in version 1 (answers inside the steps)."""
    folder = tmp_path / "v1"
    shutil.copytree(bundled(), folder)
    shutil.copyfile(
        Path(__file__).parent / "data" / "example_manual_v1.json", folder / "manual.json"
    )
    return folder


def test_version_1_and_2_read_the_same(v1: Path, v2: Path):
    a, b = load_manual(v1), load_manual(v2)
    assert json.loads((v1 / "manual.json").read_text())["version"] == 1
    assert json.loads((v2 / "manual.json").read_text())["version"] == 2
    assert manual_json(a) == manual_json(b)
    # the page: callouts with part, colour and count; the answers apart
    doc = manual_json(b)
    entry = doc["steps"][0]["components"][0]
    assert set(entry) <= {"part", "colour", "count", "submodule"} and entry["count"] >= 1
    assert "instances" not in doc["steps"][0] and "answers" in doc
    ans = answers_of(b)
    assert sum(len(s.views) for s in ans.main.steps) == len(ans.main.instances)
    # every callout entry's count is the number of instances the answers give it
    for st, sa in zip(b.main.steps, ans.main.steps, strict=True):
        assert [c.count for c in st.components] == [len(i) for i in sa.instances_of]


def test_strip_writes_the_page_only(tmp_path: Path):
    out = tmp_path / "user"
    m = strip_manual(bundled(), out)
    assert m.answers is None
    assert not list(out.glob("*_ids.png"))
    doc = json.loads((out / "manual.json").read_text())
    assert "answers" not in doc and all("camera" in s for s in doc["steps"])
    full = load_manual(bundled())
    assert [s.components for s in m.all_steps()] == [s.components for s in full.all_steps()]
    nocam = strip_manual(bundled(), tmp_path / "nocam", cameras=False)
    assert all(s.camera is None for s in nocam.all_steps())
    with pytest.raises(ManualFormatError, match="no answers"):
        answers_of(nocam)
    with pytest.raises(Exception, match="already exists"):
        strip_manual(bundled(), out)


@pytest.mark.parametrize("predictor", ["synthesis", "mepnet"])
def test_a_stripped_manual_gives_the_same_plan(tmp_path: Path, predictor: str):
    """No predictor reads the answers: without them, the plan is the same."""
    stripped = strip_manual(bundled(), tmp_path / "user")
    p = make_predictor(predictor)

    def poses(manual: Any) -> list[Any]:
        run = run_manual(manual, p)
        return [(b.name, s.placed) for b in run.builds for s in b.steps]

    full = poses(load_manual(bundled()))
    assert poses(stripped) == full
    assert sum(pl is not None for _, placed in full for pl in placed) > 20


def test_oracles_say_they_need_the_answers(tmp_path: Path):
    stripped = strip_manual(bundled(), tmp_path / "user")
    with pytest.raises(ManualFormatError, match="oracle and needs the manual's answers"):
        run_manual(stripped, make_predictor("oracle"))


BAD: list[tuple[str, Any, str]] = [
    ("top level list", lambda d: d.clear() or d.update({"x": 1}), "schema"),
    (
        "missing camera key",
        lambda d: d["steps"][0]["camera"].pop("scale"),
        "step 1: 'scale' is missing",
    ),
    (
        "scale 0",
        lambda d: d["steps"][2]["camera"].update(scale=0),
        "step 3: camera scale must be > 0",
    ),
    (
        "NaN",
        lambda d: d["steps"][1]["camera"].update(elevation=float("nan")),
        "step 2: camera elevation",
    ),
    (
        "submodule out of range",
        lambda d: d["steps"][0]["components"].append({"submodule": 7, "count": 1}),
        "submodule 7 is out of range",
    ),
    (
        "count -3",
        lambda d: d["steps"][0]["components"][0].update(count=-3),
        "count -3 is out of range",
    ),
    (
        "unknown part",
        lambda d: d["steps"][0]["components"][0].update(part="99999"),
        "part '99999' is not in the library",
    ),
    (
        "instance 999",
        lambda d: d["answers"]["steps"][0]["components"][0].__setitem__(0, 999),
        "instance id 999 is out of range",
    ),
    (
        "t 1e20",
        lambda d: d["answers"]["instances"][0].update(t=[1e20, 0, 0]),
        "t must be an integer",
    ),
    (
        "t huge int",
        lambda d: d["answers"]["instances"][0].update(t=[10**20, 0, 0]),
        "is out of range",
    ),
    ("yaw 7", lambda d: d["answers"]["instances"][0].update(yaw=7), "yaw 7 is out of range"),
    (
        "empty keypoints",
        lambda d: d["answers"]["steps"][0]["instances"][0].update(keypoints=[]),
        "keypoints are empty",
    ),
    (
        "image outside",
        lambda d: d["steps"][0].update(image="../x.png"),
        "must be a file name inside",
    ),
    ("answers missing a step", lambda d: d["answers"]["steps"].pop(), "answers have"),
    (
        "image is the folder",
        lambda d: d["steps"][0].update(image="."),
        "must be a file name inside",
    ),
    (
        "image name with NUL",
        lambda d: d["steps"][0].update(image="a\x00b.png"),
        "must be a file name inside",
    ),
    (
        "image name too long",
        lambda d: d["steps"][0].update(image="x" * 300 + ".png"),
        "must be a file name inside",
    ),
    (
        "answers collide",
        lambda d: d["answers"]["instances"][1].update(
            t=d["answers"]["instances"][0]["t"],
            component=d["answers"]["instances"][0]["component"],
            yaw=d["answers"]["instances"][0]["yaw"],
        ),
        "instance",
    ),
    (
        "submodule bricks collide",
        lambda d: d["answers"]["submodules"][0]["bricks"].append(
            d["answers"]["submodules"][0]["bricks"][0]
        ),
        "answers submodule 0 brick",
    ),
]


@pytest.mark.parametrize("name, change, message", BAD, ids=[b[0] for b in BAD])
def test_the_whole_file_is_checked_on_load(v2: Path, name: str, change: Any, message: str):
    edit(v2, change)
    with pytest.raises(ManualFormatError, match="manual.json") as e:
        load_manual(v2)
    assert message in str(e.value)
    assert "\n" not in str(e.value)


@pytest.mark.parametrize("text", ["[]", "null", "3", '"x"'])
def test_a_top_level_that_is_not_an_object(tmp_path: Path, text: str):
    (tmp_path / "manual.json").write_text(text)
    with pytest.raises(ManualFormatError, match="top level must be an object"):
        load_manual(tmp_path)


def test_not_utf8(tmp_path: Path):
    (tmp_path / "manual.json").write_bytes(b'{"schema": "\xff\xfe"}')
    with pytest.raises(ManualFormatError, match="not UTF-8"):
        load_manual(tmp_path)


def test_a_16_bit_grey_step_image_is_read_as_grey(tmp_path: Path):
    grey = np.full((32, 32), 30000, np.uint16)  # mid grey, not white
    grey[:8] = 65535
    Image.fromarray(grey).save(tmp_path / "g.png")
    with Image.open(tmp_path / "g.png") as im:
        assert im.mode.startswith("I")
    rgb = read_step_image(tmp_path / "g.png", (32, 32))
    assert rgb.dtype == np.uint8 and rgb.shape == (32, 32, 3)
    assert abs(int(rgb[20, 5, 0]) - round(30000 / 65535 * 255)) <= 1
    assert (rgb[0] == 255).all()


def png_header_only(path: Path, w: int, h: int) -> None:
    """A PNG that claims w x h pixels (and holds almost no data)."""

    def chunk(kind: bytes, data: bytes) -> bytes:
        return (
            struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))
        )

    ihdr = struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0)
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IEND", b""))


def test_huge_and_truncated_pictures_are_refused_with_their_name(tmp_path: Path):
    png_header_only(tmp_path / "huge.png", 20000, 20000)
    with pytest.raises(ManualFormatError, match="huge.png.*(too large|larger than)"):
        read_step_image(tmp_path / "huge.png", (256, 256))
    ids = np.zeros((64, 64), np.uint16)
    ids[10:20, 10:20] = 3
    Image.fromarray(ids).save(tmp_path / "ids.png")
    data = (tmp_path / "ids.png").read_bytes()
    (tmp_path / "cut_ids.png").write_bytes(data[: len(data) // 2])
    with pytest.raises(ManualFormatError, match="cut_ids.png: unreadable instance map"):
        read_instance_map(tmp_path / "cut_ids.png")
    assert read_instance_map(tmp_path / "ids.png")[15, 15] == 2


def test_strip_command(tmp_path: Path):
    r = subprocess.run(
        [
            sys.executable,
            "-m",
            "mepnet.manual",
            "strip",
            str(bundled()),
            "--out",
            str(tmp_path / "u"),
            "--no-cameras",
        ],
        capture_output=True,
        text=True,
    )
    assert r.returncode == 0, r.stderr
    assert "no cameras" in r.stdout
    r = subprocess.run(
        [
            sys.executable,
            "-m",
            "mepnet.manual",
            "strip",
            str(tmp_path / "missing"),
            "--out",
            str(tmp_path / "v"),
        ],
        capture_output=True,
        text=True,
    )
    assert r.returncode == 2 and r.stderr.count("\n") == 1 and "missing" in r.stderr
    assert not (tmp_path / "v").exists()


def test_errors_after_loading_name_the_manual_and_step(v2: Path):
    (v2 / "step_004.png").write_bytes(b"not a png at all")
    m = load_manual(v2)  # the file exists: found when the step is read
    with pytest.raises(ManualFormatError) as e:
        run_manual(m, make_predictor("synthesis"))
    assert "step_004.png" in str(e.value) and f"{v2} step 4" in str(e.value)


def test_a_generated_manual_held_in_memory_reads_as_written_and_loaded(tmp_path: Path):
    """Training keeps its generated manuals in memory (no PNGs written and read back): every
    step's picture, instance map, camera, callout and answers are those of the same manual
    written by write_manual and read by load_manual; writing one writes no file."""
    from mepnet import _brickgeom as _bg
    from mepnet.manual import generated_manual, write_manual

    m = _bg.synth_manual(1, {"image_size": 64, "components": (6, 10)})  # one submodule
    held = generated_manual(m, {"kind": "synthetic", "seed": 1})
    files = load_manual(write_manual(tmp_path / "m", m, {"kind": "synthetic"}, "mepnet.synth"))
    assert held.submodules and len(held.submodules) == len(files.submodules)
    assert held.parts == files.parts and held.image_size == files.image_size
    pairs = list(zip(held.all_steps(), files.all_steps(), strict=True))
    assert len(pairs) > 4
    for a, b in pairs:
        assert (a.index, a.camera, a.components) == (b.index, b.camera, b.components)
        assert a.where.replace(str(held.path), str(files.path)) == b.where
        ia, ib = a.image(), b.image()
        assert ia.dtype == ib.dtype == np.uint8 and np.array_equal(ia, ib), a.where
    ha, fa = answers_of(held), answers_of(files)
    assert ha.shapes == fa.shapes
    for hb, fb in zip([ha.main, *ha.submodules], [fa.main, *fa.submodules], strict=True):
        assert hb.instances == fb.instances
        for x, y in zip(hb.steps, fb.steps, strict=True):
            assert (x.instances_of, x.views) == (y.instances_of, y.views)
            assert x.ids().dtype == y.ids().dtype and np.array_equal(x.ids(), y.ids())
    assert not Path(str(held.path)).exists()
