"""The manual dataset format: one folder per manual, read and written here.

A manual folder holds ``manual.json`` and, per step, ``step_NNN.png`` (the manual image) and
``step_NNN_ids.png`` (a 16-bit instance map: instance id + 1, 0 on the background). Submodule
steps use ``subKK_step_NNN.png``. The schema (version 1) is documented in ``docs/dataset.md``;
:func:`load_manual` returns typed objects and :class:`StepDataset` indexes the steps of many
manuals as a map-style dataset (``len`` / ``[i]``) that torch's ``DataLoader`` accepts.
"""

from __future__ import annotations

import json
import os
import shutil
import sys
import tempfile
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from mepnet import _brickgeom as _bg
from mepnet.state import make_camera

SCHEMA = "mepnet.manual"
VERSION = 1


class ManualFormatError(ValueError):
    """A manual folder or manual.json that does not follow the format."""


# ---------------------------------------------------------------------------------------------
# Typed objects


@dataclass(frozen=True)
class ComponentRef:
    """A library part or a submodule of the same manual (index into ``Manual.submodules``)."""

    part: str | None = None
    submodule: int | None = None

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> ComponentRef:
        if "part" in d:
            return cls(part=str(d["part"]))
        if "submodule" in d:
            return cls(submodule=int(d["submodule"]))
        raise ManualFormatError(f"component {d!r} has neither 'part' nor 'submodule'")

    def to_json(self) -> dict[str, Any]:
        return {"part": self.part} if self.part is not None else {"submodule": self.submodule}


@dataclass(frozen=True)
class Instance:
    """A placed component: its pose on the lattice and LDraw colour."""

    id: int
    component: ComponentRef
    yaw: int
    t: tuple[int, int, int]
    colour: int = 16


@dataclass(frozen=True)
class InstanceView:
    """How a new instance appears in its step image."""

    id: int
    attach: str
    keypoints: list[tuple[float, float]]
    box: tuple[int, int, int, int] | None
    visible_fraction: float

    @property
    def keypoint(self) -> tuple[float, float]:
        """The keypoint (the first topmost brick's, for a submodule)."""
        return self.keypoints[0]


@dataclass(frozen=True)
class StepComponent:
    """One component type added in a step, with how many instances."""

    component: ComponentRef
    count: int
    instances: list[int]


@dataclass
class Step:
    """A manual step: camera, components, their poses and 2D annotations, and images."""

    index: int
    camera: dict[str, Any]
    components: list[StepComponent]
    views: list[InstanceView]
    image_path: Path
    ids_path: Path
    #: The manual's image size (W, H); an image of another size is resized to it.
    size: tuple[int, int] | None = None

    def image(self) -> np.ndarray:
        """The manual image, (H, W, 3) uint8, at the manual's image size (an image of another
        size is resized, and that is said once per manual on stderr)."""
        from PIL import Image, UnidentifiedImageError

        try:
            with Image.open(self.image_path) as im:
                rgb = im.convert("RGB")
                if self.size is not None and rgb.size != tuple(self.size):
                    _note_resize(self.image_path, rgb.size, self.size)
                    rgb = rgb.resize(tuple(self.size), Image.Resampling.BILINEAR)
                return np.asarray(rgb)
        except FileNotFoundError:
            raise ManualFormatError(
                f"{self.image_path}: step {self.index} image is missing"
            ) from None
        except (UnidentifiedImageError, OSError) as e:
            raise ManualFormatError(f"{self.image_path}: unreadable step image ({e})") from None

    def ids(self) -> np.ndarray:
        """The instance map, (H, W) int32: instance id, -1 on the background."""
        from PIL import Image

        with Image.open(self.ids_path) as im:
            return np.asarray(im, dtype=np.int32) - 1

    def camera_object(self) -> _bg.Camera:
        """The step camera as a :class:`mepnet.Camera`."""
        return make_camera(self.camera)

    @property
    def instance_ids(self) -> list[int]:
        """Ids of the instances this step adds."""
        return [v.id for v in self.views]


_RESIZE_NOTED: set[Path] = set()


def _note_resize(path: Path, got: tuple[int, int], want: tuple[int, int]) -> None:
    if path.parent not in _RESIZE_NOTED:
        _RESIZE_NOTED.add(path.parent)
        print(
            f"mepnet: {path}: image is {got[0]}x{got[1]}, the manual says {want[0]}x{want[1]}; "
            "resized (and so are the other step images of this manual that differ)",
            file=sys.stderr,
        )


@dataclass
class Build:
    """A shape with its steps (the main model or a submodule)."""

    instances: list[Instance]
    steps: list[Step]


@dataclass
class Submodule:
    """A submodule: its bricks in its own frame and its own manual."""

    name: str
    symmetry: int
    topmost: list[int]
    bricks: list[dict[str, Any]]
    build: Build

    def component(self) -> _bg.Component:
        """The submodule as a :class:`mepnet.Component`."""
        poses = np.array([[b["yaw"], *b["t"]] for b in self.bricks], dtype=np.int64)
        return _bg.Component.from_bricks(
            self.name, [b["part"] for b in self.bricks], poses, [b["colour"] for b in self.bricks]
        )


@dataclass
class Manual:
    """A whole manual: main build, submodules, provenance."""

    path: Path
    source: dict[str, Any]
    image_size: tuple[int, int]
    parts: list[str]
    main: Build
    submodules: list[Submodule] = field(default_factory=list)

    def all_steps(self) -> list[Step]:
        """Every step: the main build's, then each submodule build's."""
        return [st for b in [self.main, *(s.build for s in self.submodules)] for st in b.steps]

    def component(self, ref: ComponentRef) -> _bg.Component:
        """The component a reference points at."""
        if ref.part is not None:
            return _bg.Component.primitive(ref.part)
        return self.submodules[int(ref.submodule)].component()  # type: ignore[arg-type]

    def assembly_before(self, step: int, build: Build | None = None) -> _bg.Assembly:
        """The base shape of step ``step`` (0-based) of a build: everything added before it."""
        build = build or self.main
        asm = _bg.Assembly()
        comps: dict[ComponentRef, _bg.Component] = {}
        for s in build.steps[:step]:
            for v in s.views:
                inst = build.instances[v.id]
                comp = comps.setdefault(inst.component, self.component(inst.component))
                asm.add(comp, inst.yaw, inst.t, inst.colour)
        return asm


# ---------------------------------------------------------------------------------------------
# Reading


def _build_from_json(d: dict[str, Any], folder: Path, size: tuple[int, int] | None = None) -> Build:
    instances = [
        Instance(
            id=i,
            component=ComponentRef.from_json(x["component"]),
            yaw=int(x["yaw"]),
            t=tuple(int(v) for v in x["t"]),  # type: ignore[arg-type]
            colour=int(x.get("colour", 16)),
        )
        for i, x in enumerate(d["instances"])
    ]
    steps = []
    for k, s in enumerate(d["steps"]):
        views = [
            InstanceView(
                id=int(v["id"]),
                attach=str(v["attach"]),
                keypoints=[tuple(p) for p in v["keypoints"]],  # type: ignore[misc]
                box=tuple(v["box"]) if v["box"] is not None else None,  # type: ignore[arg-type]
                visible_fraction=float(v["visible_fraction"]),
            )
            for v in s["instances"]
        ]
        for v in views:
            if not 0 <= v.id < len(instances):
                raise ManualFormatError(f"{folder}: step {k + 1} names unknown instance {v.id}")
        comps = [
            StepComponent(
                component=ComponentRef.from_json(c["component"]),
                count=int(c["count"]),
                instances=[int(i) for i in c["instances"]],
            )
            for c in s["components"]
        ]
        steps.append(
            Step(
                index=int(s["index"]),
                camera=dict(s["camera"]),
                components=comps,
                views=views,
                image_path=folder / s["image"],
                ids_path=folder / s["ids"],
                size=size,
            )
        )
    return Build(instances=instances, steps=steps)


def step_colour(build: Build, step: Step, ref: ComponentRef) -> int:
    """The colour the manual gives a component type in a step (its parts callout): the colour of
    the step's first instance of that type (16, the main colour, when there is none)."""
    return next(
        (
            build.instances[v.id].colour
            for v in step.views
            if build.instances[v.id].component == ref
        ),
        16,
    )


def load_manual(folder: str | os.PathLike[str]) -> Manual:
    """Read a manual folder. Raises :class:`ManualFormatError` naming the problem."""
    folder = Path(folder)
    path = folder / "manual.json"
    try:
        d = json.loads(path.read_text())
    except FileNotFoundError:
        raise ManualFormatError(f"{folder}: no manual.json (not a manual folder)") from None
    except json.JSONDecodeError as e:
        raise ManualFormatError(f"{path}: not valid JSON ({e})") from None
    if d.get("schema") != SCHEMA:
        raise ManualFormatError(f"{path}: schema is {d.get('schema')!r}, expected {SCHEMA!r}")
    if d.get("version") != VERSION:
        raise ManualFormatError(f"{path}: version {d.get('version')!r} is not supported")
    try:
        size = tuple(int(v) for v in d["image_size"])
        if len(size) != 2 or min(size) < 1:
            raise ValueError(f"image_size {d['image_size']!r} is not [width, height]")
        subs = [
            Submodule(
                name=s["name"],
                symmetry=int(s["symmetry"]),
                topmost=list(s["topmost"]),
                bricks=list(s["bricks"]),
                build=_build_from_json(s, folder, size),  # type: ignore[arg-type]
            )
            for s in d["submodules"]
        ]
        manual = Manual(
            path=folder,
            source=dict(d["source"]),
            image_size=size,  # type: ignore[arg-type]
            parts=list(d["parts"]),
            main=_build_from_json(d, folder, size),  # type: ignore[arg-type]
            submodules=subs,
        )
    except (KeyError, TypeError, ValueError) as e:
        if isinstance(e, ManualFormatError):
            raise
        raise ManualFormatError(f"{path}: malformed ({type(e).__name__}: {e})") from None
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
    for p in sorted(root.iterdir()):
        if p.is_dir() and not p.name.startswith(".") and (p / "manual.json").is_file():
            yield p


class StepDataset:
    """All steps of the main builds (and, with ``submodules=True``, of submodule builds) of the
    manuals under some folders. ``ds[i]`` is a dict: ``image`` (H, W, 3) uint8, ``ids`` (H, W)
    int32, ``step`` (the :class:`Step`), ``manual`` (the :class:`Manual`), ``build``. Training
    wraps it in a torch ``Dataset`` of tensors (``mepnet.train_data``); this module does not
    import torch, so the data tools start fast."""

    def __init__(
        self,
        roots: str | os.PathLike[str] | Sequence[str | os.PathLike[str]],
        submodules: bool = False,
    ):
        if isinstance(roots, (str, os.PathLike)):
            roots = [roots]
        self.manuals = [load_manual(p) for r in roots for p in iter_manual_dirs(r)]
        self.index: list[tuple[int, int, int]] = []  # (manual, build: -1 main / k submodule, step)
        for m, man in enumerate(self.manuals):
            self.index += [(m, -1, s) for s in range(len(man.main.steps))]
            if submodules:
                for k, sub in enumerate(man.submodules):
                    self.index += [(m, k, s) for s in range(len(sub.build.steps))]

    def __len__(self) -> int:
        return len(self.index)

    def __getitem__(self, i: int) -> dict[str, Any]:
        m, b, s = self.index[i]
        man = self.manuals[m]
        build = man.main if b < 0 else man.submodules[b].build
        step = build.steps[s]
        return {
            "image": step.image(),
            "ids": step.ids(),
            "step": step,
            "step_index": s,
            "build": build,
            "manual": man,
        }


# ---------------------------------------------------------------------------------------------
# Writing


def _png(path: Path, array: np.ndarray) -> None:
    from PIL import Image

    # fixed compression settings keep files byte-identical across runs and machines
    Image.fromarray(array).save(path, format="PNG", compress_level=6)


def _build_json(build: dict[str, Any], folder: Path, prefix: str) -> dict[str, Any]:
    """Write a build's images and return its JSON form."""
    instances = [
        {
            "component": {"part": x["part"]} if "part" in x else {"submodule": x["submodule"]},
            "yaw": int(x["yaw"]),
            "t": [int(v) for v in x["t"]],
            "colour": int(x["colour"]),
        }
        for x in build["instances"]
    ]
    steps = []
    for k, s in enumerate(build["steps"]):
        name = f"{prefix}step_{k + 1:03d}"
        _png(folder / f"{name}.png", s["rgb"])
        _png(folder / f"{name}_ids.png", (s["ids"] + 1).astype(np.uint16))
        comps: dict[str, dict[str, Any]] = {}
        for i in s["instances"]:
            c = instances[i]["component"]
            key = json.dumps(c, sort_keys=True)
            entry = comps.setdefault(key, {"component": c, "count": 0, "instances": []})
            entry["count"] += 1
            entry["instances"].append(int(i))
        steps.append(
            {
                "index": k + 1,
                "image": f"{name}.png",
                "ids": f"{name}_ids.png",
                "camera": s["camera"],
                "components": list(comps.values()),
                "instances": [
                    {
                        "id": int(i),
                        "yaw": instances[i]["yaw"],
                        "t": instances[i]["t"],
                        "attach": a,
                        "keypoints": [
                            [round(float(u), 3), round(float(v), 3)] for u, v in view["keypoints"]
                        ],
                        "box": view["box"],
                        "visible_fraction": round(float(view["visible_fraction"]), 4),
                    }
                    for i, a, view in zip(s["instances"], s["attach"], s["views"], strict=True)
                ],
            }
        )
    return {"instances": instances, "steps": steps}


def write_manual(
    folder: str | os.PathLike[str], manual: dict[str, Any], source: dict[str, Any]
) -> Path:
    """Write a generated manual (the dict of ``_brickgeom.synth_manual``) to ``folder``,
    atomically: everything goes to a temporary sibling folder that is renamed at the end."""
    folder = Path(folder)
    parent = folder.parent
    parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".tmp-{folder.name}-", dir=parent))
    try:
        main = _build_json(manual["main"], tmp, "")
        subs = []
        for k, s in enumerate(manual["submodules"]):
            b = _build_json(s["build"], tmp, f"sub{k:02d}_")
            subs.append(
                {
                    "name": s["name"],
                    "symmetry": int(s["symmetry"]),
                    "topmost": [int(i) for i in s["topmost"]],
                    "bricks": [
                        {
                            "part": b2["part"],
                            "yaw": int(b2["yaw"]),
                            "t": [int(v) for v in b2["t"]],
                            "colour": int(b2["colour"]),
                        }
                        for b2 in s["bricks"]
                    ],
                    **b,
                }
            )
        parts = sorted(
            {x["component"]["part"] for x in main["instances"] if "part" in x["component"]}
            | {b2["part"] for s in subs for b2 in s["bricks"]}
        )
        size = int(manual["image_size"])
        doc = {
            "schema": SCHEMA,
            "version": VERSION,
            "source": source,
            "image_size": [size, size],
            "parts": parts,
            "submodules": subs,
            **main,
        }
        (tmp / "manual.json").write_text(json.dumps(doc, indent=1) + "\n")
        os.replace(tmp, folder)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return folder
