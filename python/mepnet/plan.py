"""Build plans: run a predictor over a whole manual (submodules first, predictions fed forward)
and write ``plan.json``, ``plan.mpd`` (LDraw, opens in LeoCAD/LDView/LPub3D/Studio and reads
back with :mod:`mepnet.ldraw`) and step overlay images."""

from __future__ import annotations

import json
import os
import shutil
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from mepnet import _brickgeom as _bg
from mepnet import ldraw
from mepnet.data import Build, ComponentRef, Manual, step_colour
from mepnet.geom import BrickGeomError, rotate_lattice
from mepnet.predictors import Prediction, Predictor, StepContext

PLAN_SCHEMA = "mepnet.plan"


def _ref_json(ref: ComponentRef, manual: Manual) -> dict[str, Any]:
    if ref.part is not None:
        return {"part": ref.part}
    return {"submodule": ref.submodule, "name": manual.submodules[int(ref.submodule)].name}  # type: ignore[arg-type]


def run_build(
    predictor: Predictor,
    manual: Manual,
    build: Build,
    comps: dict[ComponentRef, _bg.Component],
) -> tuple[list[dict[str, Any]], list[tuple[ComponentRef, int, tuple[int, int, int], int]]]:
    """Predict every step of a build on its own predictions. Returns per-step records and the
    placed instances (ref, yaw, t, colour)."""
    base = _bg.Assembly()
    steps = []
    placed = []
    for k, step in enumerate(build.steps):
        ctx = StepContext(
            step=step, base=base.copy(), components=comps, image_size=manual.image_size, truth=build
        )
        t0 = time.perf_counter()
        preds: list[Prediction] = predictor.predict(ctx)
        dt = time.perf_counter() - t0
        truth = {
            (build.instances[v.id].component, build.instances[v.id].yaw, build.instances[v.id].t)
            for v in step.views
        }
        records = []
        for p in preds:
            rec: dict[str, Any] = {
                "component": _ref_json(p.component, manual),
                "attach": p.attach,
                "failure": p.failure,
            }
            if p.t is not None:
                pos, mat = ldraw.ldraw_placement(p.yaw, p.t)
                rec.update(yaw=p.yaw, lattice=list(p.t), ldu={"position": pos, "matrix": mat})
                err = p.extra.get("error_px")
                rec["confidence"] = float(np.exp(-(err or 0.0) / 2.0)) if err is not None else None
                comp = comps[p.component]
                rec["correct"] = any(
                    r == p.component and comp.same_placement(y, t, p.yaw, p.t) for r, y, t in truth
                )
                colour = step_colour(build, step, p.component)
                try:
                    base.add(comp, p.yaw, p.t, colour)
                    placed.append((p.component, p.yaw, p.t, colour))
                except BrickGeomError as e:  # a predictor other than stage 2 may collide
                    rec["failure"] = str(e)
            records.append(rec)
        steps.append(
            {"index": k + 1, "image": step.image_path.name, "seconds": dt, "components": records}
        )
    return steps, placed


def submodule_component(
    name: str,
    placed: list[tuple[ComponentRef, int, tuple[int, int, int], int]],
    comps: dict[ComponentRef, _bg.Component],
) -> _bg.Component | None:
    """A predicted submodule as a component (its bricks in its own frame)."""
    bricks = [
        (part, (yaw + by) % 4, rotate_lattice(bt, yaw, t), col if bcol == 16 else bcol)
        for ref, yaw, t, col in placed
        for part, by, bt, bcol in comps[ref].bricks
    ]
    if not bricks:
        return None
    return _bg.Component.from_bricks(
        name,
        [b[0] for b in bricks],
        np.array([[b[1], *b[2]] for b in bricks], dtype=np.int64),
        [b[3] for b in bricks],
    )


def make_plan(
    manual: Manual, predictor: Predictor
) -> tuple[dict[str, Any], dict[ComponentRef, _bg.Component], dict[str, list]]:
    """The plan of a whole manual: submodules first (their predicted shapes become the
    components of later steps), then the main model."""
    comps: dict[ComponentRef, _bg.Component] = {}
    for b in [manual.main] + [s.build for s in manual.submodules]:
        for inst in b.instances:
            if inst.component.part is not None:
                comps.setdefault(inst.component, _bg.Component.primitive(inst.component.part))
    placed_by_build: dict[str, list] = {}
    subs = []
    for k, sub in enumerate(manual.submodules):
        steps, placed = run_build(predictor, manual, sub.build, comps)
        placed_by_build[sub.name] = placed
        comp = submodule_component(sub.name, placed, comps) or sub.component()
        comps[ComponentRef(submodule=k)] = comp
        subs.append({"name": sub.name, "steps": steps})
    steps, placed = run_build(predictor, manual, manual.main, comps)
    placed_by_build["main"] = placed
    n = sum(len(s["components"]) for b in [*subs, {"steps": steps}] for s in b["steps"])
    correct = sum(
        bool(c.get("correct"))
        for b in [*subs, {"steps": steps}]
        for s in b["steps"]
        for c in s["components"]
    )
    plan = {
        "schema": PLAN_SCHEMA,
        "version": 1,
        "manual": str(manual.path),
        "predictor": predictor.name,
        "units": {
            "lattice": "x, z half-studs (10 LDU), y plates (8 LDU), y up",
            "ldu": "LDraw frame, y down",
        },
        "submodules": subs,
        "steps": steps,
        "components": n,
        "correct": correct,
    }
    return plan, comps, placed_by_build


def plan_ldraw(
    manual: Manual, placed_by_build: dict[str, list], steps_by_build: dict[str, list]
) -> ldraw.LDrawFile:
    """The plan as an LDraw file: the main model, one submodel per submodule, one step per
    manual step."""

    def model(name: str, placed: list, steps: list[dict[str, Any]]) -> ldraw.LDrawModel:
        it = iter(placed)
        out_steps = []
        for s in steps:
            refs = []
            for c in s["components"]:
                if c.get("lattice") is None or c.get("failure"):
                    continue
                ref, yaw, t, colour = next(it)
                pos, mat = ldraw.ldraw_placement(yaw, t)
                if ref.part is not None:
                    refs.append(
                        ldraw.LDrawRef(
                            name=f"{ref.part}.dat",
                            colour=colour,
                            position=tuple(pos),
                            matrix=tuple(tuple(r) for r in mat),
                        )
                    )
                else:
                    sub = manual.submodules[int(ref.submodule)].name  # type: ignore[arg-type]
                    refs.append(
                        ldraw.LDrawRef(
                            name=sub.lower(),
                            colour=colour,
                            position=tuple(pos),
                            matrix=tuple(tuple(r) for r in mat),
                            is_submodel=True,
                        )
                    )
            if refs:
                out_steps.append(refs)
        return ldraw.LDrawModel(name=name, steps=out_steps, title=f"mepnet plan: {name}")

    models = [model("main.ldr", placed_by_build["main"], steps_by_build["main"])]
    models += [
        model(s.name.lower(), placed_by_build[s.name], steps_by_build[s.name])
        for s in manual.submodules
    ]
    return ldraw.LDrawFile(name="plan.mpd", models=models)


def overlay(
    image: np.ndarray,
    placed_new: list[tuple[_bg.Component, int, tuple[int, int, int]]],
    camera: _bg.Camera,
) -> np.ndarray:
    """The manual image with the predicted new components outlined in magenta and tinted."""
    h, w = image.shape[:2]
    asm = _bg.Assembly()
    for comp, yaw, t in placed_new:
        try:
            asm.add(comp, yaw, t)
        except BrickGeomError:
            pass
    out = image.copy()
    if len(asm) == 0:
        return out
    mask = _bg.render(asm, camera, w, h, line_px=0)["ids"] >= 0
    tint = np.array([255, 0, 255], dtype=np.float32)
    out[mask] = (0.6 * out[mask] + 0.4 * tint).astype(np.uint8)
    edge = mask & ~(
        np.roll(mask, 1, 0) & np.roll(mask, -1, 0) & np.roll(mask, 1, 1) & np.roll(mask, -1, 1)
    )
    out[edge] = (255, 0, 255)
    return out


def write_plan(manual: Manual, predictor: Predictor, out: str | os.PathLike[str]) -> dict[str, Any]:
    """Run the predictor over the manual and write plan.json, plan.mpd and overlays to ``out``
    (atomically: a temporary folder renamed at the end; an existing ``out`` is replaced)."""
    from PIL import Image

    out = Path(out)
    plan, comps, placed = make_plan(manual, predictor)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".tmp-{out.name}-", dir=out.parent))
    try:
        steps_by_build = {
            "main": plan["steps"],
            **{s["name"]: s["steps"] for s in plan["submodules"]},
        }
        ldraw.write(tmp / "plan.mpd", plan_ldraw(manual, placed, steps_by_build))
        (tmp / "plan.json").write_text(json.dumps(plan, indent=1) + "\n")
        builds = [("main", manual.main)] + [(s.name, s.build) for s in manual.submodules]
        for name, build in builds:
            it = iter(placed[name])
            prefix = (
                "" if name == "main" else "".join(c if c.isalnum() else "_" for c in name) + "_"
            )
            for s, step in zip(steps_by_build[name], build.steps, strict=True):
                new = []
                for c in s["components"]:
                    if c.get("lattice") is None or c.get("failure"):
                        continue
                    ref, yaw, t, _ = next(it)
                    new.append((comps[ref], yaw, t))
                img = overlay(step.image(), new, step.camera_object())
                Image.fromarray(img).save(tmp / f"{prefix}overlay_{s['index']:03d}.png")
        if out.exists():
            shutil.rmtree(out)
        os.replace(tmp, out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return plan
