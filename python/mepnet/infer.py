"""The main job: a building manual in, an executable build plan out.

    python -m mepnet.infer [MANUAL_DIR] [--out DIR] [--predictor P] [--weights W]
    python -m mepnet.infer MODEL.mpd [--out DIR]

A manual folder (``manual.json`` + step images; with no argument, the example manual bundled in
the package): the predictor (by default the detector with the bundled slim weights, or
``--weights``; or ``synthesis`` / ``abys`` / ``direct3d`` / ``oracle`` / ``oracle-noisy`` / ``oracle-abys``) runs over the manual tree,
submodules first, on its own predictions, and ``plan.json``, ``plan.mpd``, step overlays and
``report.html`` (the plan to look at in a browser, :mod:`mepnet.report`) are written to
``--out``; a per-step table is printed, with accuracy against the manual's ground truth.

An LDraw model (.ldr/.mpd): its existing build plan is printed submodules first, with every
step's lattice and LDraw poses and whether it is physically valid; ``--out`` renders every step.
"""

from __future__ import annotations

import argparse
import sys
from importlib import resources
from pathlib import Path

from mepnet import _brickgeom as _bg
from mepnet import ldraw
from mepnet.cli import ArgumentParser, run
from mepnet.errors import ConfigError, ManualFormatError, OutputError
from mepnet.files import atomic_folder, check_replaceable
from mepnet.geom import BrickGeomError, manual_camera, submodule_from_placed
from mepnet.ldraw.io import ModelCheck, StepCheck, StepItem, build_order, check, resolve_colour

#: The writer name in the manifest of the LDraw path's step-image folders.
LDRAW_WRITER = "mepnet.infer (LDraw steps)"


def bundled_example() -> Path:
    """Path of the bundled example LDraw model."""
    return Path(str(resources.files("mepnet") / "data" / "example.mpd"))


def bundled_manual() -> Path:
    """Path of the bundled example manual folder (the default of ``python -m mepnet.infer``)."""
    return Path(str(resources.files("mepnet") / "data" / "example_manual"))


def _step_state(step: StepCheck) -> str:
    if step.results is None:
        return "not checked (parts outside the library)"
    bad = [msg for ok, msg in step.results if not ok]
    return "valid" if not bad else f"INVALID: {bad[0]}"


def print_plan(file: ldraw.LDrawFile, checks: list[ModelCheck]) -> None:
    """Print the plan table, submodules first."""
    for m in build_order(checks):
        model = checks[m]
        kind = "main model" if m == 0 else "submodule"
        print(f"\n{model.name} ({kind}, {len(model.steps)} steps)")
        print(
            f"  {'step':>4}  {'component':<28} {'yaw':>3}  {'lattice (x, y, z)':<18} "
            f"{'LDU (x, y, z)':<22} attach"
        )
        for step, items in zip(model.steps, model.items, strict=True):
            results = step.results or [(False, "-")] * len(items)
            for k, (it, (ok, kind_or_err)) in enumerate(zip(items, results, strict=True)):
                if it.part is not None:
                    name = f"{it.part} {_bg.part_info(it.part)['name']}"
                elif it.submodel is not None:
                    name = f"[{checks[it.submodel].name}]"
                else:
                    name = f"{it.name} (not in library)"
                pos, _ = ldraw.ldraw_placement(it.yaw, it.t)
                ldu = "(" + ", ".join(f"{v:g}" for v in pos) + ")"
                lat = "(" + ", ".join(str(v) for v in it.t) + ")"
                attach = kind_or_err if ok else ("-" if step.results is None else "FAILS")
                label = f"{step.step:>4}" if k == 0 else "    "
                print(f"  {label}  {name[:28]:<28} {it.yaw:>3}  {lat:<18} {ldu:<22} {attach}")
            print(f"        -> {_step_state(step)}")


def render_steps(file: ldraw.LDrawFile, checks: list[ModelCheck], out: Path, size: int) -> int:
    """Render the cumulative shape after every step of every model into the folder ``out``
    (written atomically); returns the number of images."""
    with atomic_folder(out, LDRAW_WRITER) as tmp:
        return _render_steps(checks, tmp, size)


def _render_steps(checks: list[ModelCheck], out: Path, size: int) -> int:
    from PIL import Image

    written = 0
    comps: dict[int, _bg.Component] = {}
    lift = 1024  # model frames may reach below y = 0; build high, then drop onto the ground
    order = build_order(checks)
    # LDraw's colour inheritance: a submodel is drawn in the colour of the first reference that
    # places it (16 resolved from the main model down), as instruction tools draw its steps
    inherited = {0: 16}
    for m in reversed(order):  # parents before the submodels they place
        for it in (it for items in checks[m].items for it in items):
            if it.submodel is not None and it.submodel not in inherited:
                inherited[it.submodel] = resolve_colour(it.colour, inherited.get(m, 16))
    for m in order:
        model = checks[m]
        steps = [
            [
                (
                    _component(it, comps),
                    it.yaw,
                    (it.t[0], it.t[1] + lift, it.t[2]),
                    resolve_colour(it.colour, inherited.get(m, 16)),
                )
                for it in items
                if it.blocker is None
            ]
            for items in model.items
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
        safe = "".join(c if c.isalnum() or c in "-_" else "_" for c in model.name)
        for s, step in enumerate(steps):
            for comp, yaw, t, col in step:
                try:
                    asm.add(comp, yaw, (t[0], t[1] - drop, t[2]), col)
                except BrickGeomError:
                    pass
            if len(asm) == 0:
                continue
            r = _bg.render(asm, camera, size, size, supersample=3)
            Image.fromarray(r.rgb).save(out / f"{safe}_step_{s + 1:03d}.png")
            written += 1
        if m != 0 and checks[m].placeable:
            placed = [
                (c, y, (t[0], t[1] - lift, t[2]), col) for step in steps for c, y, t, col in step
            ]
            comps[m] = submodule_from_placed(model.name, placed)
    return written


def _component(it: StepItem, comps: dict[int, _bg.Component]) -> _bg.Component:
    """What a placeable item places: a library part, or a submodel built before."""
    if it.submodel is not None:
        return comps[it.submodel]
    return _bg.Component.primitive(str(it.part))


def run_manual_folder(path: Path, args: argparse.Namespace) -> int:
    """The manual-folder path: predictor over the manual tree, plan files, per-step table."""
    from tqdm import tqdm

    from mepnet.manual import load_manual
    from mepnet.plan import run_manual, write_plan
    from mepnet.stage2 import make_predictor

    manual = load_manual(path)
    out = args.out  # checked by _main before any work
    predictor = make_predictor(args.predictor, sigma=args.sigma, weights=args.weights)
    with tqdm(
        total=len(manual.all_steps()),
        unit="step",
        leave=False,  # an error then stays one line
        file=sys.stderr,
        disable=args.no_progress,
    ) as bar:
        run = run_manual(manual, predictor, on_step=lambda: bar.update(1))
    plan = write_plan(run, out)
    print(f"mepnet: manual {path}: predictor {plan['predictor']}")
    for name, steps in [
        *((s["name"], s["steps"]) for s in plan["submodules"]),
        ("main model", plan["steps"]),
    ]:
        print(f"\n{name}")
        print(
            f"  {'step':>4}  {'component':<22} {'yaw':>3}  {'lattice (x, y, z)':<18} {'attach':<11} ok"
        )
        for s in steps:
            for j, c in enumerate(s["components"]):
                comp = c["component"].get("part") or f"[{c['component'].get('name')}]"
                lat = (
                    "(" + ", ".join(str(v) for v in c["lattice"]) + ")" if c.get("lattice") else "-"
                )
                if c.get("failure"):
                    ok = "FAILED: " + c["failure"]
                elif "correct" in c:
                    ok = "yes" if c["correct"] else "no"
                else:
                    ok = "-"
                label = f"{s['index']:>4}" if j == 0 else "    "
                print(
                    f"  {label}  {comp[:22]:<22} {c.get('yaw', '-')!s:>3}  {lat:<18} {c.get('attach') or '-':<11} {ok}"
                )
    total = plan["components"]
    if "correct" in plan:
        summary = (
            f"{plan['correct']}/{total} components exactly right "
            f"({100 * plan['correct'] / max(total, 1):.1f}%), built on its own predictions; "
            f"the manual {'is' if plan['exact'] else 'is not'} built exactly right"
        )
    else:
        summary = f"{plan['placed']}/{total} components placed (the manual has no answers to score)"
    print(f"\n{summary}; wrote {out}/plan.json, plan.mpd, report.html and overlays")
    return 0


def run_ldraw(path: Path, args: argparse.Namespace) -> int:
    """The LDraw path: the file's own plan, checked step by step; ``--out``: step images."""
    file = ldraw.read(path)
    checks = check(file)
    info = ldraw.inspect(file)
    print(
        f"mepnet: model {path.name}: {info['models']} models, {info['steps']} steps, "
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
    return 0


def main(argv: list[str] | None = None) -> int:
    """Entry point; returns the exit status (2 on bad input, with one line on stderr; 130 on
    Ctrl-C)."""
    from mepnet.stage2 import PREDICTORS

    ap = ArgumentParser(prog="python -m mepnet.infer", description=__doc__.splitlines()[0])
    ap.add_argument(
        "model",
        nargs="?",
        help="a manual folder (manual.json + step images) or an LDraw model (.ldr/.mpd); default: the bundled example manual",
    )
    ap.add_argument(
        "--out",
        type=Path,
        help="output folder (plan files for a manual; step images for an LDraw model); an "
        "existing folder is replaced only when it is an earlier output nobody added to",
    )
    ap.add_argument(
        "--size",
        type=int,
        default=256,
        help="image size in pixels for LDraw step images (16..2048, default 256)",
    )
    ap.add_argument(
        "--predictor",
        default="mepnet",
        choices=PREDICTORS,
        help="for manual folders (default mepnet)",
    )
    ap.add_argument(
        "--weights",
        type=Path,
        help="network weights (model.safetensors): the detector's for --predictor mepnet and "
        "abys (default: the shipped slim weights), Direct3D's for --predictor direct3d",
    )
    ap.add_argument(
        "--sigma", type=float, default=1.0, help="keypoint noise for --predictor oracle-noisy"
    )
    ap.add_argument("--no-progress", action="store_true", help="no progress bar")
    args = ap.parse_args(argv)
    return run("mepnet.infer", lambda: _main(args))


def _main(args: argparse.Namespace) -> int:
    if not 16 <= args.size <= 2048:
        raise ConfigError(f"--size must be within 16..2048 pixels, got {args.size}")
    path = Path(args.model) if args.model else bundled_manual()
    if args.model is None:
        print(f"mepnet: the bundled example manual ({path}) with the shipped slim detector")
        args.out = args.out or Path("mepnet-example-plan")
    if path.is_dir():  # a manual's plan goes to --out, by default NAME-plan beside it
        from mepnet.plan import PLAN_WRITER

        args.out = args.out or Path(f"{path.resolve().name}-plan")  # (`infer .` names it too)
    if args.out is not None:
        # before the work: never replace what is not ours
        check_replaceable(args.out, PLAN_WRITER if path.is_dir() else LDRAW_WRITER)
        if args.out.resolve() == path.resolve():
            raise OutputError(f"{args.out}: is the input itself (choose a new --out)")
    if path.is_dir():
        return run_manual_folder(path, args)
    if not path.exists():
        raise ManualFormatError(f"{path}: no such manual folder or LDraw file")
    return run_ldraw(path, args)


if __name__ == "__main__":
    raise SystemExit(main())
