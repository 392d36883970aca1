"""Reading, checking and writing manual folders (``manual.json`` + step images).

Version 2 (written since the page and the answers were separated) keeps what the page shows
at the top level -- image size, per build the steps with their image, camera (optional) and
parts callout (part id + colour, or submodule index, with counts) -- and everything else under
``answers`` (optional): instances and their poses, per step which instances each callout entry
adds, keypoints, boxes, attach kinds and instance maps, the submodules' bricks. Version 1
folders (answers mixed into the steps) still load. The whole file is checked on load: every
problem is a :class:`~mepnet.errors.ManualFormatError` naming the file, the step and the field.
The schema is documented in ``docs/dataset.md``.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path, PurePosixPath
from typing import Any

import numpy as np

from mepnet import _brickgeom as _bg
from mepnet.errors import ManualFormatError
from mepnet.files import atomic_folder, regular_input
from mepnet.manual.answers import (
    Answers,
    BuildAnswers,
    Instance,
    InstanceView,
    StepAnswers,
    SubmoduleShape,
    instance_json,
)
from mepnet.manual.page import (
    CAMERA_KEYS,
    MAIN_COLOUR,
    Build,
    ComponentRef,
    Manual,
    Step,
    StepComponent,
)

SCHEMA = "mepnet.manual"
VERSION = 2
#: Lattice coordinates beyond this are not a model (about 1.6 km).
MAX_COORD = 1 << 20
#: The largest image side a manual may state.
MAX_SIDE = 8192
#: The largest manual.json mepnet reads.
MAX_JSON_BYTES = 256 << 20
#: The most instances a step may add, and components a build may hold.
MAX_COUNT = 100_000


# ---------------------------------------------------------------------------------------------
# Checked access to the JSON document


class _At:
    """A place in manual.json, for messages: ``FILE: main step 3 component 1: ...``."""

    def __init__(self, path: Path, where: str = ""):
        self.path = path
        self.where = where

    def __truediv__(self, part: str) -> _At:
        return _At(self.path, f"{self.where} {part}".strip())

    def fail(self, msg: str) -> ManualFormatError:
        at = f"{self.where}: " if self.where else ""
        return ManualFormatError(f"{self.path}: {at}{msg}")

    def obj(self, v: Any, what: str) -> dict[str, Any]:
        if not isinstance(v, dict):
            raise self.fail(f"{what} must be an object, got {type(v).__name__}")
        return v

    def get(self, d: dict[str, Any], key: str) -> Any:
        if key not in d:
            raise self.fail(f"'{key}' is missing")
        return d[key]

    def list(self, v: Any, what: str) -> list[Any]:
        if not isinstance(v, list):
            raise self.fail(f"{what} must be a list, got {type(v).__name__}")
        return v

    def int(self, v: Any, what: str, lo: int | None = None, hi: int | None = None) -> int:
        if isinstance(v, bool) or not isinstance(v, int):
            raise self.fail(f"{what} must be an integer, got {v!r}")
        if (lo is not None and v < lo) or (hi is not None and v > hi):
            rng = f"{lo if lo is not None else '-inf'}..{hi if hi is not None else 'inf'}"
            raise self.fail(f"{what} {v} is out of range ({rng})")
        return v

    def num(self, v: Any, what: str) -> float:
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise self.fail(f"{what} must be a finite number, got {v!r}")
        return float(v)

    def str(self, v: Any, what: str) -> str:
        if not isinstance(v, str) or not v:
            raise self.fail(f"{what} must be a non-empty string, got {v!r}")
        return v

    def file(self, folder: Path, v: Any, what: str) -> Path:
        name = self.str(v, what)
        p = PurePosixPath(name)
        if (
            p.is_absolute()
            or not p.parts
            or ".." in p.parts
            or "\\" in name
            or "\x00" in name
            or any(len(part.encode("utf-8", "surrogateescape")) > 255 for part in p.parts)
        ):
            raise self.fail(f"{what} {name[:80]!r} must be a file name inside the manual folder")
        return folder / name


def _camera(at: _At, v: Any) -> dict[str, Any] | None:
    if v is None:
        return None
    d = at.obj(v, "camera")
    cam: dict[str, Any] = {}
    for k in CAMERA_KEYS[:4]:
        cam[k] = at.num(at.get(d, k), f"camera {k}")
    if cam["scale"] <= 0:
        raise at.fail(f"camera scale must be > 0, got {cam['scale']}")
    tr = at.list(at.get(d, "translation"), "camera translation")
    if len(tr) != 2:
        raise at.fail(f"camera translation must be [x, y], got {tr!r}")
    cam["translation"] = [at.num(x, "camera translation") for x in tr]
    return cam


def _ref(at: _At, d: dict[str, Any], n_subs: int) -> ComponentRef:
    if "part" in d:
        name = at.str(d["part"], "part")
        part = _bg.resolve_part(name)
        if part is None:
            raise at.fail(f"part {name!r} is not in the library")
        return ComponentRef(part=part)
    if "submodule" in d:
        return ComponentRef(submodule=at.int(d["submodule"], "submodule", 0, n_subs - 1))
    raise at.fail("component has neither 'part' nor 'submodule'")


def _colour(at: _At, d: dict[str, Any]) -> int:
    return at.int(d.get("colour", MAIN_COLOUR), "colour", 0, 2**31 - 1)


def _t(at: _At, v: Any) -> tuple[int, int, int]:
    t = at.list(v, "t")
    if len(t) != 3:
        raise at.fail(f"t must be [x, y, z], got {t!r}")
    return tuple(at.int(x, "t", -MAX_COORD, MAX_COORD) for x in t)  # type: ignore[return-value]


def _instances(at: _At, v: Any, n_subs: int) -> list[Instance]:
    out = []
    for i, x in enumerate(at.list(v, "instances")):
        a = at / f"instance {i}"
        x = a.obj(x, "instance")
        out.append(
            Instance(
                id=i,
                component=_ref(a, a.obj(a.get(x, "component"), "component"), n_subs),
                yaw=a.int(a.get(x, "yaw"), "yaw", 0, 3),
                t=_t(a, a.get(x, "t")),
                colour=_colour(a, x),
            )
        )
    return out


def _view(at: _At, v: Any, n_inst: int) -> InstanceView:
    v = at.obj(v, "instance view")
    iid = at.int(at.get(v, "id"), "instance id", 0, n_inst - 1)
    kps = at.list(at.get(v, "keypoints"), "keypoints")
    if not kps:
        raise at.fail(f"instance {iid}: keypoints are empty")
    keypoints = []
    for p in kps:
        p = at.list(p, "keypoint")
        if len(p) != 2:
            raise at.fail(f"instance {iid}: a keypoint must be [x, y], got {p!r}")
        keypoints.append((at.num(p[0], "keypoint"), at.num(p[1], "keypoint")))
    box = v.get("box")
    if box is not None:
        box = at.list(box, "box")
        if len(box) != 4:
            raise at.fail(f"instance {iid}: box must be [x0, y0, x1, y1], got {box!r}")
        box = tuple(at.int(b, "box") for b in box)
    return InstanceView(
        id=iid,
        attach=at.str(v.get("attach", "unknown"), "attach"),
        keypoints=keypoints,  # type: ignore[arg-type]
        box=box,  # type: ignore[arg-type]
        visible_fraction=at.num(v.get("visible_fraction", 1.0), "visible_fraction"),
    )


class _Reader:
    """Reads one manual.json (version 1 or 2) into typed objects, checking everything."""

    def __init__(self, folder: Path, doc: dict[str, Any]):
        self.folder = folder
        self.doc = doc
        self.top = _At(folder / "manual.json")
        self.version = doc.get("version")

    def read(self) -> Manual:
        at, d = self.top, self.doc
        if d.get("schema") != SCHEMA:
            raise at.fail(f"schema is {d.get('schema')!r}, expected {SCHEMA!r}")
        if self.version not in (1, 2):
            raise at.fail(f"version {self.version!r} is not supported (1 or 2)")
        size = at.list(at.get(d, "image_size"), "image_size")
        if len(size) != 2:
            raise at.fail(f"image_size {size!r} is not [width, height]")
        self.size = (
            at.int(size[0], "image width", 1, MAX_SIDE),
            at.int(size[1], "image height", 1, MAX_SIDE),
        )
        source = d.get("source", {})
        source = at.obj(source, "source")
        parts = [at.str(p, "parts entry") for p in at.list(d.get("parts", []), "parts")]
        subs_doc = [at.obj(s, "submodule") for s in at.list(d.get("submodules", []), "submodules")]
        self.n_subs = len(subs_doc)
        if self.version == 1:
            return self._read_v1(source, parts, subs_doc)
        builds = []
        for k, s in enumerate(subs_doc):
            name = (at / f"submodule {k}").str(s.get("name", f"submodule_{k}"), "name")
            builds.append(self._page_build(at / f"submodule {k}", s, name))
        main = self._page_build(at / "main", d, "main")
        manual = Manual(self.folder, source, self.size, parts, main, builds)
        if d.get("answers") is not None:
            manual.answers = self._answers_v2(manual, at.obj(d["answers"], "answers"))
        self._check_tree(manual)
        return manual

    # -- version 2 ---------------------------------------------------------------------------

    def _page_build(self, at: _At, d: dict[str, Any], name: str) -> Build:
        steps = []
        for k, s in enumerate(at.list(at.get(d, "steps"), "steps")):
            a = at / f"step {k + 1}"
            s = a.obj(s, "step")
            comps = []
            for j, c in enumerate(a.list(a.get(s, "components"), "components")):
                ca = a / f"component {j + 1}"
                c = ca.obj(c, "component")
                ref = _ref(ca, c, self.n_subs)
                count = ca.int(ca.get(c, "count"), "count", 1, MAX_COUNT)
                comps.append(StepComponent(ref, count, _colour(ca, c)))
            steps.append(self._step(a, s, k, comps, name))
        return Build(name=name, steps=steps)

    def _step(
        self, a: _At, s: dict[str, Any], k: int, comps: list[StepComponent], name: str
    ) -> Step:
        where = _step_where(self.folder, name, k)
        return Step(
            index=k + 1,
            image_path=a.file(self.folder, a.get(s, "image"), "image"),
            camera=_camera(a, s.get("camera")),
            components=comps,
            size=self.size,
            where=where,
        )

    def _build_answers(
        self, at: _At, d: dict[str, Any], build: Build, steps_doc: list[Any]
    ) -> BuildAnswers:
        instances = _instances(at, at.get(d, "instances"), self.n_subs)
        if len(steps_doc) != len(build.steps):
            raise at.fail(f"answers have {len(steps_doc)} steps, the page {len(build.steps)}")
        steps = []
        for k, (s, page) in enumerate(zip(steps_doc, build.steps, strict=True)):
            a = at / f"step {k + 1}"
            s = a.obj(s, "step answers")
            groups = [
                [a.int(i, "instance id", 0, len(instances) - 1) for i in a.list(g, "instances")]
                for g in a.list(a.get(s, "components"), "components")
            ]
            views = [
                _view(a, v, len(instances)) for v in a.list(a.get(s, "instances"), "instances")
            ]
            ids = s.get("ids")
            steps.append(
                StepAnswers(
                    instances_of=groups,
                    views=views,
                    ids_path=a.file(self.folder, ids, "ids") if ids is not None else None,
                    size=self.size,
                )
            )
            self._check_step(a, page, steps[-1], instances)
        return BuildAnswers(instances=instances, steps=steps)

    def _answers_v2(self, manual: Manual, d: dict[str, Any]) -> Answers:
        at = self.top / "answers"
        main = self._build_answers(at, d, manual.main, at.list(at.get(d, "steps"), "steps"))
        subs_doc = at.list(d.get("submodules", []), "submodules")
        if len(subs_doc) != len(manual.submodules):
            raise at.fail(
                f"answers have {len(subs_doc)} submodules, the page {len(manual.submodules)}"
            )
        subs, shapes = [], []
        for k, (s, b) in enumerate(zip(subs_doc, manual.submodules, strict=True)):
            a = at / f"submodule {k}"
            s = a.obj(s, "submodule answers")
            subs.append(self._build_answers(a, s, b, a.list(a.get(s, "steps"), "steps")))
            shapes.append(self._shape(a, s, b.name))
        return Answers(main=main, submodules=subs, shapes=shapes)

    def _shape(self, at: _At, s: dict[str, Any], name: str) -> SubmoduleShape:
        bricks = []
        for j, b in enumerate(at.list(at.get(s, "bricks"), "bricks")):
            a = at / f"brick {j}"
            b = a.obj(b, "brick")
            part = _ref(a, {"part": a.get(b, "part")}, 0).part
            bricks.append(
                (part, a.int(a.get(b, "yaw"), "yaw", 0, 3), _t(a, a.get(b, "t")), _colour(a, b))
            )
        if not bricks:
            raise at.fail("a submodule needs at least one brick")
        return SubmoduleShape(
            name=name,
            symmetry=at.int(s.get("symmetry", 1), "symmetry", 1, 4),
            topmost=[
                at.int(i, "topmost", 0, len(bricks) - 1)
                for i in at.list(s.get("topmost", [0]), "topmost")
            ],
            bricks=bricks,  # type: ignore[arg-type]
        )

    # -- version 1 ---------------------------------------------------------------------------

    def _read_v1(
        self, source: dict[str, Any], parts: list[str], subs_doc: list[dict[str, Any]]
    ) -> Manual:
        at = self.top
        names = [
            (at / f"submodule {k}").str(s.get("name", f"submodule_{k}"), "name")
            for k, s in enumerate(subs_doc)
        ]
        built = [self._build_v1(at / f"submodule {k}", s, names[k]) for k, s in enumerate(subs_doc)]
        main, main_ans = self._build_v1(at / "main", self.doc, "main")
        manual = Manual(self.folder, source, self.size, parts, main, [b for b, _ in built])
        shapes = [self._shape(at / f"submodule {k}", s, names[k]) for k, s in enumerate(subs_doc)]
        manual.answers = Answers(main=main_ans, submodules=[a for _, a in built], shapes=shapes)
        self._check_tree(manual)
        return manual

    def _build_v1(self, at: _At, d: dict[str, Any], name: str) -> tuple[Build, BuildAnswers]:
        instances = _instances(at, at.get(d, "instances"), self.n_subs)
        steps, answers = [], []
        for k, s in enumerate(at.list(at.get(d, "steps"), "steps")):
            a = at / f"step {k + 1}"
            s = a.obj(s, "step")
            views = [
                _view(a, v, len(instances)) for v in a.list(a.get(s, "instances"), "instances")
            ]
            # the callout: one entry per (component, colour), in order of first appearance
            entries: dict[tuple[ComponentRef, int], list[int]] = {}
            for j, c in enumerate(a.list(a.get(s, "components"), "components")):
                ca = a / f"component {j + 1}"
                c = ca.obj(c, "component")
                ref = _ref(ca, ca.obj(ca.get(c, "component"), "component"), self.n_subs)
                ids = [
                    ca.int(i, "instance id", 0, len(instances) - 1)
                    for i in ca.list(ca.get(c, "instances"), "instances")
                ]
                count = ca.int(ca.get(c, "count"), "count", 1, MAX_COUNT)
                if count != len(ids):
                    raise ca.fail(f"count {count} but {len(ids)} instances listed")
                for i in ids:
                    if instances[i].component != ref:
                        raise ca.fail(f"instance {i} is {instances[i].component}, not {ref}")
                    colour = instances[i].colour if ref.part is not None else MAIN_COLOUR
                    entries.setdefault((ref, colour), []).append(i)
            comps = [StepComponent(ref, len(ids), colour) for (ref, colour), ids in entries.items()]
            steps.append(self._step(a, s, k, comps, name))
            ids_file = s.get("ids")
            answers.append(
                StepAnswers(
                    instances_of=list(entries.values()),
                    views=views,
                    ids_path=a.file(self.folder, ids_file, "ids") if ids_file is not None else None,
                    size=self.size,
                )
            )
            self._check_step(a, steps[-1], answers[-1], instances)
        return Build(name=name, steps=steps), BuildAnswers(instances=instances, steps=answers)

    # -- cross-references --------------------------------------------------------------------

    def _check_step(self, at: _At, page: Step, ans: StepAnswers, instances: list[Instance]) -> None:
        if len(ans.instances_of) != len(page.components):
            raise at.fail(
                f"answers list {len(ans.instances_of)} components, the callout {len(page.components)}"
            )
        for c, ids in zip(page.components, ans.instances_of, strict=True):
            if len(ids) != c.count:
                raise at.fail(f"{c.component}: count {c.count} but {len(ids)} instances")
            for i in ids:
                if instances[i].component != c.component:
                    raise at.fail(f"instance {i} is {instances[i].component}, not {c.component}")
        listed = sorted(i for ids in ans.instances_of for i in ids)
        viewed = sorted(v.id for v in ans.views)
        if listed != viewed or len(set(listed)) != len(listed):
            raise at.fail("the step's instances and their views do not match")

    def _check_geometry(self, manual: Manual) -> None:
        """The answers describe real shapes: no brick of a submodule and no instance of a build
        overlaps another (an answer that collides is not a manual anyone could build)."""
        ans = manual.answers
        if ans is None:
            return
        for k, shape in enumerate(ans.shapes):
            asm = _bg.Assembly()
            for j, (part, yaw, t, colour) in enumerate(shape.bricks):
                try:
                    asm.add(_bg.Component.primitive(part), yaw, t, colour)
                except _bg.BrickGeomError as e:
                    raise self.top.fail(f"answers submodule {k} brick {j}: {e}") from None
        components = ans.components(manual)
        for key, _ in manual.builds():
            b = ans.build(key)
            asm = _bg.Assembly()
            for st in b.steps:
                for v in st.views:
                    inst = b.instances[v.id]
                    try:
                        asm.add(components[inst.component], inst.yaw, inst.t, inst.colour)
                    except _bg.BrickGeomError as e:
                        where = "answers" if key is None else f"answers submodule {key}"
                        raise self.top.fail(f"{where} instance {v.id}: {e}") from None

    def _check_tree(self, manual: Manual) -> None:
        """Submodules are used only by later builds (no cycles) and every instance id is added
        by exactly one step."""
        for k, b in enumerate(manual.submodules):
            for st in b.steps:
                for c in st.components:
                    if c.component.submodule is not None and c.component.submodule >= k:
                        raise self.top.fail(
                            f"submodule {b.name} step {st.index} uses submodule "
                            f"{c.component.submodule}, which is not built before it"
                        )
        if manual.answers is None:
            return
        self._check_geometry(manual)
        for k, (b, ans) in enumerate(
            [
                (manual.main, manual.answers.main),
                *zip(manual.submodules, manual.answers.submodules, strict=True),
            ]
        ):
            seen = [v.id for s in ans.steps for v in s.views]
            if len(seen) != len(set(seen)):
                dup = next(i for i in seen if seen.count(i) > 1)
                raise self.top.fail(f"{b.name}: instance {dup} is added by more than one step")
            del k


def load_manual(folder: str | os.PathLike[str]) -> Manual:
    """Read and check a manual folder. Raises :class:`ManualFormatError` naming the problem."""
    folder = Path(folder)
    path = folder / "manual.json"
    if not folder.is_dir():
        raise ManualFormatError(f"{folder}: not a folder")
    if not path.exists():
        raise ManualFormatError(f"{folder}: no manual.json (not a manual folder)")
    regular_input(path, "manual.json")
    if path.stat().st_size > MAX_JSON_BYTES:
        raise ManualFormatError(f"{path}: larger than {MAX_JSON_BYTES >> 20} MB, not a manual")
    try:
        raw = path.read_bytes()
    except OSError as e:
        raise ManualFormatError(f"{path}: cannot read ({e.strerror or e})") from None
    try:
        d = json.loads(raw.decode("utf-8"))
    except UnicodeDecodeError as e:
        raise ManualFormatError(f"{path}: not UTF-8 text ({e.reason} at byte {e.start})") from None
    except json.JSONDecodeError as e:
        raise ManualFormatError(f"{path}: not valid JSON ({e})") from None
    except RecursionError:
        raise ManualFormatError(f"{path}: JSON nested too deeply") from None
    if not isinstance(d, dict):
        raise ManualFormatError(f"{path}: the top level must be an object, got {type(d).__name__}")
    manual = _Reader(folder, d).read()
    missing = [st.image_path.name for st in manual.all_steps() if not st.image_path.is_file()]
    if missing:
        more = f" (and {len(missing) - 1} more)" if len(missing) > 1 else ""
        raise ManualFormatError(f"{folder}: step image {missing[0]} is missing{more}")
    return manual


def iter_manual_dirs(root: str | os.PathLike[str]) -> Iterator[Path]:
    """Manual folders under ``root`` (``root`` itself if it is one), sorted by name."""
    root = Path(root)
    if (root / "manual.json").is_file():
        yield root
        return
    if not root.is_dir():
        raise ManualFormatError(f"{root}: not a folder")
    for p in sorted(root.iterdir()):
        if p.is_dir() and not p.name.startswith(".") and (p / "manual.json").is_file():
            yield p


# ---------------------------------------------------------------------------------------------
# Writing


def _rel(path: Path, folder: Path) -> str:
    """A file's name relative to the manual folder (as written in manual.json)."""
    try:
        return path.relative_to(folder).as_posix()
    except ValueError:
        return path.name


def _page_step_json(st: Step, folder: Path, cameras: bool) -> dict[str, Any]:
    d: dict[str, Any] = {"index": st.index, "image": _rel(st.image_path, folder)}
    if cameras and st.camera is not None:
        d["camera"] = st.camera
    d["components"] = [c.to_json() for c in st.components]
    return d


def _answers_step_json(a: StepAnswers, folder: Path) -> dict[str, Any]:
    d: dict[str, Any] = {}
    if a.ids_path is not None:
        d["ids"] = _rel(a.ids_path, folder)
    d["components"] = a.instances_of
    d["instances"] = [
        {
            "id": v.id,
            "attach": v.attach,
            "keypoints": [[round(float(x), 3), round(float(y), 3)] for x, y in v.keypoints],
            "box": list(v.box) if v.box is not None else None,
            "visible_fraction": round(float(v.visible_fraction), 4),
        }
        for v in a.views
    ]
    return d


def manual_json(manual: Manual, answers: bool = True, cameras: bool = True) -> dict[str, Any]:
    """The version-2 ``manual.json`` document of a manual (``answers=False``: as users have
    it; ``cameras=False``: without cameras either)."""
    doc: dict[str, Any] = {
        "schema": SCHEMA,
        "version": VERSION,
        "source": manual.source,
        "image_size": list(manual.image_size),
        "parts": manual.parts,
        "submodules": [
            {"name": b.name, "steps": [_page_step_json(s, manual.path, cameras) for s in b.steps]}
            for b in manual.submodules
        ],
        "steps": [_page_step_json(s, manual.path, cameras) for s in manual.main.steps],
    }
    if answers and manual.answers is not None:
        ans: Answers = manual.answers

        def build(b: BuildAnswers) -> dict[str, Any]:
            return {
                "instances": [instance_json(x) for x in b.instances],
                "steps": [_answers_step_json(s, manual.path) for s in b.steps],
            }

        doc["answers"] = {
            **build(ans.main),
            "submodules": [
                {
                    "symmetry": shape.symmetry,
                    "topmost": shape.topmost,
                    "bricks": [
                        {"part": p, "yaw": y, "t": list(t), "colour": c}
                        for p, y, t, c in shape.bricks
                    ],
                    **build(b),
                }
                for b, shape in zip(ans.submodules, ans.shapes, strict=True)
            ],
        }
    return doc


def _png(path: Path, array: np.ndarray) -> None:
    from PIL import Image

    # fixed compression settings keep files byte-identical across runs and machines
    Image.fromarray(array).save(path, format="PNG", compress_level=6)


def _step_where(folder: Path, build: str, k: int) -> str:
    """How messages name step ``k`` (0-based) of build ``build`` ("main" or a submodule's)."""
    if build == "main":
        return f"{folder} step {k + 1}"
    return f"{folder} submodule {build} step {k + 1}"


@dataclass
class _HeldStep(Step):
    """A step whose picture is held in memory (:func:`generated_manual`), not read from a file."""

    pixels: np.ndarray | None = field(default=None, repr=False, compare=False)

    def image(self) -> np.ndarray:
        assert self.pixels is not None
        return self.pixels.copy()


@dataclass
class _HeldStepAnswers(StepAnswers):
    """Step answers whose instance map is held in memory (:func:`generated_manual`)."""

    id_map: np.ndarray | None = field(default=None, repr=False, compare=False)

    def ids(self) -> np.ndarray:
        assert self.id_map is not None
        return self.id_map.copy()


def _generated_build(
    build: dict[str, Any],
    tmp: Path | None,
    folder: Path,
    prefix: str,
    name: str,
    size: tuple[int, int],
) -> tuple[Build, BuildAnswers]:
    """Write a generated build's images into ``tmp`` (renamed to ``folder`` later); its page
    and answers. With ``tmp`` None the pictures and instance maps stay in memory, in the steps
    (:func:`generated_manual`)."""

    def ref(x: dict[str, Any]) -> ComponentRef:
        return (
            ComponentRef(part=x["part"])
            if "part" in x
            else ComponentRef(submodule=int(x["submodule"]))
        )

    instances = [
        Instance(i, ref(x), int(x["yaw"]), tuple(int(v) for v in x["t"]), int(x["colour"]))  # type: ignore[arg-type]
        for i, x in enumerate(build["instances"])
    ]
    steps, answers = [], []
    for k, s in enumerate(build["steps"]):
        stem = f"{prefix}step_{k + 1:03d}"
        ids16 = (np.asarray(s["ids"]) + 1).astype(np.uint16)  # as the instance map file holds it
        if tmp is not None:
            _png(tmp / f"{stem}.png", s["rgb"])
            _png(tmp / f"{stem}_ids.png", ids16)
        entries: dict[tuple[ComponentRef, int], list[int]] = {}
        for i in s["instances"]:
            inst = instances[int(i)]
            colour = inst.colour if inst.component.part is not None else MAIN_COLOUR
            entries.setdefault((inst.component, colour), []).append(int(i))
        page = Step(
            index=k + 1,
            image_path=folder / f"{stem}.png",
            camera=dict(s["camera"]),
            components=[StepComponent(r, len(ids), c) for (r, c), ids in entries.items()],
            size=size,
            where=_step_where(folder, name, k),
        )
        ans = StepAnswers(
            instances_of=list(entries.values()),
            views=[
                InstanceView(
                    id=int(i),
                    attach=str(a),
                    # rounded as manual.json stores them: a manual held in memory reads
                    # as the same manual written and loaded
                    keypoints=[
                        (round(float(u), 3), round(float(v), 3)) for u, v in view["keypoints"]
                    ],
                    box=tuple(view["box"]) if view["box"] is not None else None,  # type: ignore[arg-type]
                    visible_fraction=round(float(view["visible_fraction"]), 4),
                )
                for i, a, view in zip(s["instances"], s["attach"], s["views"], strict=True)
            ],
            ids_path=folder / f"{stem}_ids.png",
            size=size,
        )
        if tmp is None:  # what the files would read back as: uint8 RGB, int32 ids (-1 outside)
            page = _HeldStep(**vars(page), pixels=np.ascontiguousarray(s["rgb"], dtype=np.uint8))
            ans = _HeldStepAnswers(**vars(ans), id_map=ids16.astype(np.int32) - 1)
        steps.append(page)
        answers.append(ans)
    return Build(name, steps), BuildAnswers(instances, answers)


def _generated(
    manual: dict[str, Any], source: dict[str, Any], folder: Path, tmp: Path | None
) -> Manual:
    """The :class:`Manual` of a generated or converted manual dict, its pictures written into
    ``tmp`` (or held in memory when ``tmp`` is None)."""
    side = int(manual["image_size"])
    size = (side, side)
    main, main_ans = _generated_build(manual["main"], tmp, folder, "", "main", size)
    subs, subs_ans, shapes = [], [], []
    for k, s in enumerate(manual["submodules"]):
        b, a = _generated_build(s["build"], tmp, folder, f"sub{k:02d}_", s["name"], size)
        subs.append(b)
        subs_ans.append(a)
        shapes.append(
            SubmoduleShape(
                name=s["name"],
                symmetry=int(s["symmetry"]),
                topmost=[int(i) for i in s["topmost"]],
                bricks=[
                    (
                        b2["part"],
                        int(b2["yaw"]),
                        tuple(int(v) for v in b2["t"]),
                        int(b2["colour"]),
                    )  # type: ignore[misc]
                    for b2 in s["bricks"]
                ],
            )
        )
    parts = sorted(
        {x.component.part for x in main_ans.instances if x.component.part is not None}
        | {p for sh in shapes for p, *_ in sh.bricks}
    )
    return Manual(folder, source, size, parts, main, subs, Answers(main_ans, subs_ans, shapes))  # type: ignore[arg-type]


def write_manual(
    folder: str | os.PathLike[str], manual: dict[str, Any], source: dict[str, Any], writer: str
) -> Path:
    """Write a generated or converted manual (the dict of ``_brickgeom.synth_manual`` /
    ``render_plan``) to ``folder`` atomically (:func:`mepnet.files.atomic_folder`; ``folder``
    must not exist)."""
    folder = Path(folder)
    with atomic_folder(folder, writer, replace=False) as tmp:
        m = _generated(manual, source, folder, tmp)
        (tmp / "manual.json").write_text(json.dumps(manual_json(m), indent=1) + "\n")
    return folder


def generated_manual(manual: dict[str, Any], source: dict[str, Any]) -> Manual:
    """A generated manual (the dict of ``_brickgeom.synth_manual``) as the :class:`Manual`
    that :func:`write_manual` then :func:`load_manual` give, held in memory: no files are
    written, the steps carry their pictures and instance maps (for training, which reads each
    generated manual once). Its ``path`` and image paths name no files."""
    return _generated(manual, source, Path("<generated>"), None)


def strip_manual(
    src: str | os.PathLike[str], out: str | os.PathLike[str], cameras: bool = True
) -> Manual:
    """Write ``src`` as a user would have it to the new folder ``out``: the page only (step
    images and callouts, cameras unless ``cameras=False``), no answers and no instance maps."""
    import shutil

    manual = load_manual(src)
    with atomic_folder(out, "mepnet.manual strip", replace=False) as tmp:
        for st in manual.all_steps():
            target = tmp / _rel(st.image_path, manual.path)
            target.parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(st.image_path, target)
        doc = manual_json(manual, answers=False, cameras=cameras)
        (tmp / "manual.json").write_text(json.dumps(doc, indent=1) + "\n")
    return load_manual(out)
