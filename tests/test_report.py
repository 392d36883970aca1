"""report.html (mepnet.report): what the page holds, checked on the HTML, and what a real
browser shows (headless Chromium: skipped when it is not installed)."""

from __future__ import annotations

import base64
import copy
import io
import json
import re
import shutil
import subprocess
import sys
from html.parser import HTMLParser
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from PIL import Image

#: The browser the screenshot test opens the report in (Debian: apt-get install chromium).
CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")


class Page(HTMLParser):
    """The parts of a report page the tests read: step sections (id -> their images' sources,
    and their text), summary figures (data-key -> the value's text) and every src / href."""

    def __init__(self, text: str) -> None:
        super().__init__()
        self.sections: dict[str, list[str]] = {}
        self.section_text: dict[str, str] = {}
        self.summary: dict[str, str] = {}
        self.links: list[str] = []
        self._section: str | None = None
        self._key: str | None = None
        self._in_summary = False
        self._in_dd = False
        self.feed(text)

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        a = dict(attrs)
        if tag == "section" and "step" in (a.get("class") or "").split():
            self._section = str(a["id"])
            self.sections[self._section] = []
            self.section_text[self._section] = ""
        if tag == "section" and a.get("id") == "summary":
            self._in_summary = True
        if tag == "div" and self._in_summary and a.get("data-key"):
            self._key = a["data-key"]
            self.summary[self._key] = ""
        if tag == "dd" and self._key is not None:
            self._in_dd = True
        if tag == "img" and self._section is not None:
            self.sections[self._section].append(str(a.get("src")))
        for attr in ("src", "href"):
            if a.get(attr):
                self.links.append(str(a[attr]))

    def handle_endtag(self, tag: str) -> None:
        if tag == "section":
            self._section = None
            self._in_summary = False
        if tag == "div":
            self._key = None
        if tag == "dd":
            self._in_dd = False

    def handle_data(self, data: str) -> None:
        if self._key is not None and self._in_dd:
            self.summary[self._key] += data
        if self._section is not None:
            self.section_text[self._section] += data


def png_of(uri: str) -> Image.Image:
    """The image a PNG data URI holds (fails the test for anything else)."""
    prefix = "data:image/png;base64,"
    assert uri.startswith(prefix), uri[:40]
    data = base64.b64decode(uri[len(prefix) :], validate=True)
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    img = Image.open(io.BytesIO(data))
    img.load()
    return img


def step_ids(plan: dict[str, Any]) -> list[str]:
    """The section ids the report gives the plan's steps, in build order."""
    ids = [
        f"sub{k}-step-{s['index']}"
        for k, sub in enumerate(plan["submodules"])
        for s in sub["steps"]
    ]
    return ids + [f"main-step-{s['index']}" for s in plan["steps"]]


@pytest.fixture(scope="module")
def plan_folder(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """``python -m mepnet.infer`` on the bundled example manual (the oracle predictor: the
    report is under test, not the network)."""
    out = tmp_path_factory.mktemp("report") / "plan"
    r = subprocess.run(
        [sys.executable, "-m", "mepnet.infer", "--predictor", "oracle", "--out", str(out)],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert r.returncode == 0, r.stderr
    assert "report.html" in r.stdout
    return out


@pytest.fixture(scope="module")
def example_run() -> Any:
    """The bundled example manual run in-process (plan document, manual, components)."""
    from mepnet.infer import bundled_manual
    from mepnet.manual import load_manual
    from mepnet.plan import plan_json, run_manual
    from mepnet.stage2 import make_predictor

    manual = load_manual(bundled_manual())
    run = run_manual(manual, make_predictor("oracle"))
    return plan_json(run), manual, run.components


def test_infer_writes_the_report_with_a_section_per_step(plan_folder: Path):
    from mepnet.files import MANIFEST

    plan = json.loads((plan_folder / "plan.json").read_text())
    text = (plan_folder / "report.html").read_text()
    page = Page(text)
    # written with the rest of the folder (in its manifest: replaced by the next run)
    assert "report.html" in json.loads((plan_folder / MANIFEST).read_text())["files"]
    # one section per step of every build, in build order, each with its three pictures
    assert list(page.sections) == step_ids(plan)
    for sid, sources in page.sections.items():
        assert len(sources) == 3, sid
        for src in sources:
            assert png_of(src).size == (256, 256), sid
    # the table of contents and the prev / next links point at the sections
    anchors = {link[1:] for link in page.links if link.startswith("#")}
    assert set(page.sections) <= anchors
    # self-contained: nothing but data URIs and anchors
    assert all(link.startswith(("data:image/png;base64,", "#")) for link in page.links)
    assert not re.search(r"<link|@import|url\(\s*['\"]?(?!data:)", text)


def test_summary_figures_equal_the_plan(plan_folder: Path):
    plan = json.loads((plan_folder / "plan.json").read_text())
    page = Page((plan_folder / "report.html").read_text())
    steps = [*plan["steps"], *(s for sub in plan["submodules"] for s in sub["steps"])]
    s = page.summary
    assert s["manual"].startswith("example_manual")
    assert s["predictor"].strip() == plan["predictor"] == "oracle"
    assert s["builds"].startswith(f"{len(plan['submodules']) + 1} ")
    assert int(s["steps"]) == len(steps)
    assert int(s["components"]) == plan["components"]
    assert s["placed"] == f"{plan['placed']} of {plan['components']}"
    total = plan["components"]
    assert s["accuracy"].startswith(f"{plan['correct']}/{total} exactly right")
    assert f"({100 * plan['correct'] / total:.1f}%)" in s["accuracy"]
    assert s["exact"] == ("yes" if plan["exact"] else "no")
    assert s["cameras"] == f"{len(steps)} given"
    all_steps = [*(t for b in plan["submodules"] for t in b["steps"]), *plan["steps"]]
    assert s["flagged"] == f"{sum(1 for t in all_steps if t['flags'])} of {len(all_steps)}"


def test_steps_show_poses_confidence_flags_and_revisions(plan_folder: Path):
    plan = json.loads((plan_folder / "plan.json").read_text())
    page = Page((plan_folder / "report.html").read_text())
    for sid, step in zip(
        step_ids(plan),
        [*(s for b in plan["submodules"] for s in b["steps"]), *plan["steps"]],
        strict=True,
    ):
        text = page.section_text[sid]
        for c in step["components"]:
            assert "(" + ", ".join(str(v) for v in c["lattice"]) + ")" in text
            assert "(" + ", ".join(f"{v:.3g}" for v in c["ldu"]["position"]) + ")" in text
        # the step's confidence as a number, its flags and revisions ("none" when empty)
        assert f"confidence{step['confidence']:.3g}" in text, sid
        for key in ("flags", "revisions"):
            shown = "none" if not step[key] else ""
            assert f"{key}{shown}" in text, (sid, key)


def test_bad_steps_show_as_such_and_new_fields_need_no_report_change(example_run: Any):
    from mepnet.report import report_html

    plan, manual, components = example_run
    plan = copy.deepcopy(plan)
    first, second = plan["steps"][0], plan["steps"][1]
    # a step whose camera could not be estimated: nothing placed
    first.update(
        camera=None,
        camera_source="estimated",
        camera_failure="camera could not be estimated: no luck",
    )
    for c in first["components"]:
        for key in ("yaw", "lattice", "ldu", "confidence", "correct"):
            c.pop(key, None)
        c["failure"] = "camera could not be estimated: no luck"
    # fields a later change adds: per step confidence, flags and revisions, and one unknown
    second.update(
        confidence=0.42,
        flags=["unexplained pixels"],
        revisions=[{"step": 1, "component": "3003", "from": [0, 3, 0], "to": [2, 3, 0]}],
        novel_field="shown anyway",
        # other solutions no picture tells apart: the second component turned, and one
        # alternative that is not well formed (shown as it is)
        alternatives=[
            [{"index": 1, "yaw": 3, "lattice": [7, 3, -2], "ldu": {}}],
            [{"index": 99}],
        ],
    )
    second["components"][0]["novel_component_field"] = 7
    page_text = report_html(plan, manual, components)
    page = Page(page_text)
    a, b = page.section_text["main-step-1"], page.section_text["main-step-2"]
    assert "not placed" in a and "camera could not be estimated: no luck" in a
    assert "nothing placed yet" in a  # no shape to render: said, not drawn
    assert "unexplained pixels" in b and "0.42" in b and "shown anyway" in b
    assert "novel_component_field" in b and "from0, 3, 0to2, 3, 0" in b  # the revision, nested
    # the alternatives by the component's row in the step's table (from 1)
    name = page.section_text["main-step-2"]
    assert "alternatives no picture tells apart" in name and "#2 " in name
    assert "yaw 3 at (7, 3, -2)" in name and "index99" in name
    assert page.summary["flagged"] == f"1 of {len(page.sections)}"
    assert (
        page.summary["cameras"]
        == f"1 estimated, {len(page.sections) - 1} given (1 without a camera)"
    )
    # the first step's pictures: the manual's, the overlay's missing note, nothing built yet
    assert len(page.sections["main-step-1"]) == 1
    # a later step still renders the shape built so far: with a default view without a camera
    second.update(camera=None)
    page = Page(report_html(plan, manual, components))
    assert "a default view" in page.section_text["main-step-2"]


def test_report_writing_never_raises(
    example_run: Any, tmp_path: Path, capsys: pytest.CaptureFixture[str]
):
    from mepnet.report import write_report

    plan, manual, components = example_run
    broken = copy.deepcopy(plan)
    broken["steps"][0]["components"][0].update(lattice="not a position", yaw=None)
    broken["steps"][1]["components"][0]["component"] = {"part": "no-such-part"}
    write_report(tmp_path, broken, manual, components)
    page = Page((tmp_path / "report.html").read_text())
    assert (
        "main-step-1" in page.sections and "no such component" in page.section_text["main-step-2"]
    )
    # a document that is not a plan at all: a page saying so, one line on stderr
    write_report(tmp_path, {"steps": "garbage"}, manual, {})
    assert "The report failed" in (tmp_path / "report.html").read_text()
    assert "report is incomplete" in capsys.readouterr().err


def chromium(*args: str, cwd: Path) -> subprocess.CompletedProcess[bytes]:
    assert CHROMIUM is not None
    return subprocess.run(
        [
            CHROMIUM,
            "--headless",
            "--no-sandbox",  # tests run as root in CI containers
            "--disable-gpu",
            "--hide-scrollbars",
            f"--user-data-dir={cwd / 'profile'}",
            *args,
        ],
        capture_output=True,
        timeout=120,
        cwd=cwd,
    )


def screenshot(html: Path, out: Path) -> np.ndarray:
    r = chromium(f"--screenshot={out}", "--window-size=1200,2000", html.as_uri(), cwd=out.parent)
    assert r.returncode == 0 and out.is_file(), r.stderr.decode(errors="replace")[-2000:]
    return np.asarray(Image.open(out).convert("RGB")).astype(int)


def colourful(rgb: np.ndarray) -> int:
    """Pixels of a strong colour (bricks; the page itself is greys and a few small badges)."""
    return int(((rgb.max(axis=2) - rgb.min(axis=2)) > 60).sum())


@pytest.mark.skipif(
    CHROMIUM is None, reason="chromium is not installed (Debian: apt-get install chromium)"
)
def test_report_opens_in_headless_chromium(plan_folder: Path, tmp_path: Path):
    plan = json.loads((plan_folder / "plan.json").read_text())
    report = plan_folder / "report.html"
    shot = screenshot(report, tmp_path / "shot.png")
    assert shot.shape == (2000, 1200, 3)
    # not blank: a good share of the window is drawn (text, tables, pictures)
    background = (np.abs(shot - [246, 247, 249]).sum(axis=2) < 12) | (shot.min(axis=2) > 250)
    assert (~background).mean() > 0.05, (~background).mean()
    # the pictures are decoded and shown: the same page without them has far fewer colours
    bare = tmp_path / "bare.html"
    bare.write_text(re.sub(r"data:image/png;base64,[A-Za-z0-9+/=]+", "", report.read_text()))
    without = screenshot(bare, tmp_path / "bare.png")
    assert colourful(shot) > colourful(without) + 20_000, (colourful(shot), colourful(without))
    # the DOM the browser built: every step's section, with its pictures as 256 px PNGs
    r = chromium("--dump-dom", report.as_uri(), cwd=tmp_path)
    assert r.returncode == 0, r.stderr.decode(errors="replace")[-2000:]
    dom = Page(r.stdout.decode())
    assert list(dom.sections) == step_ids(plan)
    assert all(png_of(src).size == (256, 256) for srcs in dom.sections.values() for src in srcs)
    assert sum(len(srcs) for srcs in dom.sections.values()) == 3 * len(dom.sections)
