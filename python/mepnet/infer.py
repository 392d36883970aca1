"""The main job: a building manual in, an executable build plan out.

    python -m mepnet.infer [MODEL] [--out DIR]

Until the detector lands, this reads a build plan that already exists (an LDraw model with
steps; with no argument, the example bundled in the package), and prints, submodules first,
every step's components with their lattice and LDraw poses and whether each step is physically
valid (connected, no collision). With ``--out`` it also renders every step as a manual-style
image with brickgeom's rasterizer.
"""

from __future__ import annotations

import argparse
import sys
from importlib import resources
from pathlib import Path
from typing import Any

from mepnet import _brickgeom as _bg
from mepnet import ldraw
from mepnet.geom import BrickGeomError, manual_camera, rotate_lattice


def bundled_example() -> Path:
    """Path of the bundled example model."""
    return Path(str(resources.files("mepnet") / "data" / "example.mpd"))


def build_order(checks: list[dict[str, Any]], root: int = 0) -> list[int]:
    """Model indices with every submodel before the models that use it (``root`` last)."""
    order: list[int] = []
    seen: set[int] = set()

    def visit(m: int) -> None:
        if m in seen:
            return
        seen.add(m)
        for step in checks[m]["items"]:
            for it in step:
                if it["kind"] == "submodel":
                    visit(it["submodel"])
        order.append(m)

    if checks:
        visit(root)
    return order


def _step_state(step: dict[str, Any]) -> str:
    if step["results"] is None:
        return "not checked (parts outside the library)"
    bad = [msg for ok, msg in step["results"] if not ok]
    return "valid" if not bad else f"INVALID: {bad[0]}"


def print_plan(file: ldraw.LDrawFile, checks: list[dict[str, Any]]) -> None:
    """Print the plan table, submodules first."""
    for m in build_order(checks):
        model = checks[m]
        kind = "main model" if m == 0 else "submodule"
        print(f"\n{model['name']} ({kind}, {len(model['steps'])} steps)")
        print(
            f"  {'step':>4}  {'component':<28} {'yaw':>3}  {'lattice (x, y, z)':<18} "
            f"{'LDU (x, y, z)':<22} attach"
        )
        for step, items in zip(model["steps"], model["items"], strict=True):
            results = step["results"] or [(False, "-")] * len(items)
            for k, (it, (ok, kind_or_err)) in enumerate(zip(items, results, strict=True)):
                if it["kind"] == "part":
                    name = f"{it['part']} {_bg.part_info(it['part'])['name']}"
                elif it["kind"] == "submodel":
                    name = f"[{checks[it['submodel']]['name']}]"
                else:
                    name = f"{it['name']} (not in library)"
                pos, _ = ldraw.ldraw_placement(it["yaw"], tuple(it["t"]))
                ldu = "(" + ", ".join(f"{v:g}" for v in pos) + ")"
                lat = "(" + ", ".join(str(v) for v in it["t"]) + ")"
                attach = kind_or_err if ok else ("-" if step["results"] is None else "FAILS")
                label = f"{step['step']:>4}" if k == 0 else "    "
                print(f"  {label}  {name[:28]:<28} {it['yaw']:>3}  {lat:<18} {ldu:<22} {attach}")
            print(f"        -> {_step_state(step)}")


def render_steps(file: ldraw.LDrawFile, checks: list[dict[str, Any]], out: Path, size: int) -> int:
    """Render the cumulative shape after every step of every model; returns images written."""
    from PIL import Image

    out.mkdir(parents=True, exist_ok=True)
    written = 0
    comps: dict[int, _bg.Component] = {}
    lift = 1024  # model frames may reach below y = 0; build high, then drop onto the ground
    for m in build_order(checks):
        model = checks[m]
        steps = [
            [
                (
                    _bg.Component.primitive(it["part"])
                    if it["kind"] == "part"
                    else comps[it["submodel"]],
                    it["yaw"],
                    (it["t"][0], it["t"][1] + lift, it["t"][2]),
                    it["colour"],
                )
                for it in items
                if it["blocker"] is None
            ]
            for items in model["items"]
        ]
        final = _bg.Assembly()
        for comp, yaw, t, col in (x for step in steps for x in step):
            try:
                final.add(comp, yaw, t, col)
            except BrickGeomError:
                pass  # overlapping real parts are left out, as in `ldraw info`
        if len(final) == 0:
            continue
        drop = final.bounds()[0][1]
        camera = manual_camera(final, drop=drop)
        asm = _bg.Assembly()
        safe = "".join(c if c.isalnum() or c in "-_" else "_" for c in model["name"])
        for s, step in enumerate(steps):
            for comp, yaw, t, col in step:
                try:
                    asm.add(comp, yaw, (t[0], t[1] - drop, t[2]), col)
                except BrickGeomError:
                    pass
            if len(asm) == 0:
                continue
            r = _bg.render(asm, camera, size, size, supersample=3)
            Image.fromarray(r["rgb"]).save(out / f"{safe}_step_{s + 1:03d}.png")
            written += 1
        if m != 0 and checks[m]["placeable"]:
            comps[m] = submodule_component(model["name"], [x for step in steps for x in step], lift)
    return written


def submodule_component(
    name: str, placed: list[tuple[_bg.Component, int, tuple[int, int, int], int]], lift: int
) -> _bg.Component:
    """A submodule component in its model's own frame from its placed (lifted) components."""
    import numpy as np

    parts, poses, colours = [], [], []
    for comp, yaw, t, col in placed:
        for part, byaw, bt, bcol in comp.bricks:
            r = rotate_lattice(bt, yaw, t)
            parts.append(part)
            poses.append([(yaw + byaw) % 4, r[0], r[1] - lift, r[2]])
            colours.append(col if bcol == 16 else bcol)
    return _bg.Component.from_bricks(name, parts, np.array(poses, dtype=np.int64), colours)


def main(argv: list[str] | None = None) -> int:
    """Entry point; returns the exit status (2 on bad input, with one line on stderr)."""
    ap = argparse.ArgumentParser(prog="python -m mepnet.infer", description=__doc__.splitlines()[0])
    ap.add_argument(
        "model", nargs="?", help="LDraw model (.ldr/.mpd); default: the bundled example"
    )
    ap.add_argument("--out", type=Path, help="folder for rendered step images")
    ap.add_argument("--size", type=int, default=256, help="image size in pixels (default 256)")
    args = ap.parse_args(argv)
    path = Path(args.model) if args.model else bundled_example()
    try:
        file = ldraw.read(path)
        checks = _bg.check_ldraw(file.to_dict())
        info = ldraw.inspect(file)
        what = "bundled example" if args.model is None else "model"
        print(
            f"mepnet: {what} {path.name}: {info['models']} models, {info['steps']} steps, "
            f"{info['parts']} parts ({info['known_parts']} in the library)"
        )
        print_plan(file, checks)
        print(
            f"\n{info['steps_checked']} of {info['steps']} steps checked: {info['steps_valid']} valid, "
            f"{info['steps_invalid']} invalid, {info['steps_unverified']} unverified"
        )
        if args.out:
            n = render_steps(file, checks, args.out, args.size)
            print(f"wrote {n} step images to {args.out}")
    except BrickGeomError as e:
        print(f"mepnet.infer: error: {e}", file=sys.stderr)
        return 2
    except OSError as e:
        print(f"mepnet.infer: error: {e.filename or path}: {e.strerror or e}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
