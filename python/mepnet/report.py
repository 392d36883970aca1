"""The plan report: ``report.html``, one self-contained page a user opens in a browser.

:func:`write_report` is called by :func:`mepnet.plan.write_plan` into the plan folder it is
writing, so the report lands atomically with ``plan.json``, ``plan.mpd`` and the overlays. The
page holds a summary (the figures ``mepnet.infer`` prints, cameras given or estimated, flagged
steps), a table of contents, and per step of every build: the manual picture, the predicted
placement drawn over it (the step's ``overlay_NNN.png``), the plan as built so far rendered with
the step's camera, the components with their lattice and LDraw poses, and the step's
confidence, flags and revisions. Every picture is a PNG ``data:`` URI: the file alone shows
everything, with no external resource.

The report reads the plan document (``plan.json``) generically: a step or component field it
does not know is still shown, and a field it expects but the plan lacks shows "—". Writing the
report never fails the plan: a step without a camera, an unplaced component or a picture that
cannot be drawn shows as such.
"""

from __future__ import annotations

import base64
import html
import io
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from mepnet import _brickgeom as _bg
from mepnet.errors import MepnetError
from mepnet.files import atomic_write_bytes
from mepnet.geom import BrickGeomError, manual_camera
from mepnet.manual import Build, ComponentRef, Manual, Step, make_camera

#: The report's file name in the plan folder.
REPORT_NAME = "report.html"
#: Pictures are embedded at most this many pixels wide or high (larger ones are scaled down).
MAX_PICTURE_PX = 384
#: Step fields the report always shows ("—" when the plan has none).
STEP_FIELDS = ("confidence", "flags", "revisions")
#: Step fields shown elsewhere on the page (the rest are listed generically).
_STEP_SHOWN = {"index", "image", "seconds", "components", "alternatives", *STEP_FIELDS}
_CAMERA_KEYS = {"camera", "camera_source", "camera_fit", "camera_how", "camera_failure"}
#: Component fields shown in the table's own columns (the rest go to its last column).
_COMPONENT_SHOWN = {
    "component", "colour", "yaw", "lattice", "ldu", "attach", "confidence", "correct", "failure"
}  # fmt: skip
NONE = "—"


@dataclass
class Picture:
    """One embedded picture: a PNG data URI, or why there is none."""

    caption: str
    uri: str | None = None
    missing: str | None = None


def write_report(
    folder: Path, plan: dict[str, Any], manual: Manual, components: dict[ComponentRef, Any]
) -> None:
    """Write ``folder/report.html`` for the plan document ``plan`` of ``manual``
    (``components``: the plan run's components, submodules as built; overlays are read from
    ``folder``). Never raises for what the plan or the manual holds: on an unexpected error
    the page says what went wrong, and one line goes to stderr."""
    try:
        page = report_html(plan, manual, components, folder)
    except Exception as err:  # a bug here must not cost the user the plan written beside it
        print(
            f"mepnet: {folder / REPORT_NAME}: the report is incomplete ({err!r})", file=sys.stderr
        )
        page = _page(
            "mepnet plan report", f"<p class='error'>The report failed: {_e(repr(err))}</p>"
        )
    # file names need not be UTF-8 (undecodable bytes arrive as surrogates): shown escaped
    atomic_write_bytes(folder / REPORT_NAME, page.encode("utf-8", errors="backslashreplace"))


def report_html(
    plan: dict[str, Any],
    manual: Manual,
    components: dict[ComponentRef, Any],
    overlays: Path | None = None,
) -> str:
    """The report page as a string (see :func:`write_report`); ``overlays``: the folder
    holding the plan's overlay images (None: the overlay pictures show as missing)."""
    builds = _builds(plan, manual)
    sections = [
        (anchor, label, build, s, st)
        for anchor, label, build, steps in builds
        for s, st in zip(steps, _steps_of(build, len(steps)), strict=True)
    ]
    ids = [_step_id(anchor, s) for anchor, _, _, s, _ in sections]
    body = [_summary(plan, builds)]
    shapes: dict[str, _bg.Assembly] = {}
    for i, (anchor, label, build, s, st) in enumerate(sections):
        asm = shapes.setdefault(anchor, _bg.Assembly())
        notes = _add_step(asm, s, components, st)
        pictures = [
            _manual_picture(st),
            _overlay_picture(overlays, anchor, build, s),
            _built_picture(asm, s, st, manual.image_size, notes),
        ]
        prev_id = ids[i - 1] if i > 0 else None
        next_id = ids[i + 1] if i + 1 < len(ids) else None
        body.append(_step_section(ids[i], label, len(build.steps), s, pictures, prev_id, next_id))
    name = Path(str(plan.get("manual", "manual"))).name
    return _page(f"mepnet plan report: {name}", "\n".join(body), _contents(builds))


# ---------------------------------------------------------------------------------------------
# The plan document, read generically


def _builds(plan: dict[str, Any], manual: Manual) -> list[tuple[str, str, Build, list[dict]]]:
    """Per build, in build order (submodules, then the main model): its anchor, label, the
    manual's build and the plan's step dicts."""
    out = []
    subs = plan.get("submodules") or []
    for k, sub in enumerate(subs):
        build = manual.submodules[k] if k < len(manual.submodules) else Build(f"submodule {k}", [])
        label = f"{sub.get('name', build.name)} (submodule {k + 1} of {len(subs)})"
        out.append((f"sub{k}", label, build, list(sub.get("steps") or [])))
    out.append(("main", "main model", manual.main, list(plan.get("steps") or [])))
    return out


def _steps_of(build: Build, n: int) -> list[Step | None]:
    """The manual's steps beside the plan's ``n`` (None where the manual has fewer)."""
    return [build.steps[k] if k < len(build.steps) else None for k in range(n)]


def _step_id(anchor: str, s: dict[str, Any]) -> str:
    return f"{anchor}-step-{s.get('index', '')}"


def _components(s: dict[str, Any]) -> list[dict[str, Any]]:
    return [c for c in s.get("components") or [] if isinstance(c, dict)]


def _placed(c: dict[str, Any]) -> bool:
    return c.get("lattice") is not None


def _flagged(s: dict[str, Any]) -> bool:
    return bool(s.get("flags"))


def _status(s: dict[str, Any]) -> str:
    """``failed`` (a component not placed), ``wrong``, ``right`` (every component right) or
    ``placed`` (no answers to score)."""
    comps = _components(s)
    if any(not _placed(c) or c.get("failure") for c in comps):
        return "failed"
    if any(c.get("correct") is False for c in comps):
        return "wrong"
    if comps and all(c.get("correct") is True for c in comps):
        return "right"
    return "placed"


def _ref(c: dict[str, Any]) -> ComponentRef | None:
    ref = c.get("component") or {}
    if ref.get("part") is not None:
        return ComponentRef(part=str(ref["part"]))
    if ref.get("submodule") is not None:
        return ComponentRef(submodule=int(ref["submodule"]))
    return None


_PART_NAMES: dict[str, str] = {}


def _component_name(c: dict[str, Any]) -> str:
    ref = c.get("component") or {}
    if ref.get("part") is not None:
        part = str(ref["part"])
        if part not in _PART_NAMES:
            try:
                _PART_NAMES[part] = " ".join(_bg.part_info(part)["name"].split())
            except (BrickGeomError, KeyError):
                _PART_NAMES[part] = ""
        return f"{part} {_PART_NAMES[part]}".strip()
    if ref.get("submodule") is not None:
        return f"[{ref.get('name') or 'submodule ' + str(ref['submodule'])}]"
    return str(ref) or NONE


# ---------------------------------------------------------------------------------------------
# Pictures


def _png_uri(rgb: np.ndarray) -> str:
    """A PNG data URI of an (H, W, 3) uint8 image, scaled to :data:`MAX_PICTURE_PX`."""
    from PIL import Image

    img = Image.fromarray(np.ascontiguousarray(rgb[..., :3]).astype(np.uint8))
    if max(img.size) > MAX_PICTURE_PX:
        img.thumbnail((MAX_PICTURE_PX, MAX_PICTURE_PX))
    buf = io.BytesIO()
    img.save(buf, format="PNG", optimize=True)
    return "data:image/png;base64," + base64.b64encode(buf.getvalue()).decode("ascii")


def _manual_picture(st: Step | None) -> Picture:
    pic = Picture("manual picture")
    if st is None:
        pic.missing = "the manual has no such step"
        return pic
    try:
        pic.uri = _png_uri(st.image())
    except (MepnetError, OSError) as err:
        pic.missing = f"cannot read the picture: {err}"
    return pic


def overlay_name(build: Build, anchor: str, s: dict[str, Any]) -> str:
    """The overlay file :func:`mepnet.plan.write_plan` writes for a step."""
    prefix = (
        "" if anchor == "main" else "".join(ch if ch.isalnum() else "_" for ch in build.name) + "_"
    )
    return f"{prefix}overlay_{int(s.get('index', 0)):03d}.png"


def _overlay_picture(folder: Path | None, anchor: str, build: Build, s: dict[str, Any]) -> Picture:
    pic = Picture("predicted placement (magenta)")
    if s.get("camera") is None and "camera" in s:
        pic.caption = "no camera: nothing drawn over the picture"
    if folder is None:
        pic.missing = "no overlay"
        return pic
    from PIL import Image

    try:
        with Image.open(folder / overlay_name(build, anchor, s)) as img:
            pic.uri = _png_uri(np.asarray(img.convert("RGB")))
    except (OSError, ValueError) as err:
        pic.missing = f"no overlay ({err.__class__.__name__})"
    return pic


def _add_step(
    asm: _bg.Assembly, s: dict[str, Any], components: dict[ComponentRef, Any], st: Step | None
) -> list[str]:
    """Add the step's placed components to the build's shape; returns what could not be."""
    notes = []
    for c in _components(s):
        if not _placed(c):
            continue
        ref = _ref(c)
        comp = components.get(ref) if ref is not None else None
        if comp is None:
            notes.append(f"{_component_name(c)}: no such component")
            continue
        try:
            t = tuple(int(v) for v in c["lattice"])
            asm.add(comp, int(c.get("yaw", 0)), t, int(c.get("colour", 16)))
        except (BrickGeomError, TypeError, ValueError) as err:
            notes.append(f"{_component_name(c)}: {err}")
    return notes


def _built_picture(
    asm: _bg.Assembly, s: dict[str, Any], st: Step | None, size: tuple[int, int], notes: list[str]
) -> Picture:
    pic = Picture("the plan as built so far")
    if len(asm) == 0:
        pic.missing = "nothing placed yet"
        return pic
    try:
        if s.get("camera"):
            camera = make_camera(s["camera"])
        else:
            camera = manual_camera(asm)
            pic.caption += " (no camera for this step: a default view)"
        w, h = size
        pic.uri = _png_uri(_bg.render(asm, camera, w, h).rgb)
    except (BrickGeomError, KeyError, TypeError, ValueError) as err:
        pic.missing = f"cannot render: {err}"
    if notes:
        pic.caption += "; left out: " + "; ".join(notes)
    return pic


# ---------------------------------------------------------------------------------------------
# HTML


def _e(text: Any) -> str:
    return html.escape(str(text), quote=True)


def value_html(v: Any) -> str:
    """Any JSON value as HTML: "—" for null, lists and objects nested."""
    if v is None:
        return NONE
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, float):
        return f"{v:.3g}"
    if isinstance(v, (int, str)):
        return _e(v) if v != "" else NONE
    if isinstance(v, list):
        if not v:
            return "none"
        if all(not isinstance(x, (list, dict)) for x in v):
            return ", ".join(value_html(x) for x in v)
        return "<ul>" + "".join(f"<li>{value_html(x)}</li>" for x in v) + "</ul>"
    if isinstance(v, dict):
        if not v:
            return NONE
        rows = "".join(f"<dt>{_e(k)}</dt><dd>{value_html(x)}</dd>" for k, x in v.items())
        return f"<dl class='kv'>{rows}</dl>"
    return _e(v)


def _summary(plan: dict[str, Any], builds: list[tuple[str, str, Build, list[dict]]]) -> str:
    steps = [s for _, _, _, ss in builds for s in ss]
    total = int(plan.get("components", sum(len(_components(s)) for s in steps)))
    placed = int(plan.get("placed", sum(_placed(c) for s in steps for c in _components(s))))
    sources: dict[str, int] = {}
    for s in steps:
        src = str(s.get("camera_source") or "given")
        sources[src] = sources.get(src, 0) + 1
    cameras = ", ".join(f"{n} {src}" for src, n in sorted(sources.items())) or NONE
    failed = sum(1 for s in steps if s.get("camera") is None)
    if failed:
        cameras += f" ({failed} without a camera)"
    if "correct" in plan:
        right = int(plan["correct"])
        accuracy = f"{right}/{total} exactly right ({100 * right / max(total, 1):.1f}%)"
        exact = value_html(plan.get("exact"))
    else:
        accuracy = exact = f"{NONE} (the manual has no answers)"
    has_flags = any("flags" in s for s in steps)
    flagged = f"{sum(_flagged(s) for s in steps)} of {len(steps)}" if has_flags else NONE
    seconds = sum(float(s.get("seconds") or 0.0) for s in steps)
    rows = [
        ("manual", "manual", f"{_e(Path(str(plan.get('manual', ''))).name)} "
         f"<span class='dim'>{_e(plan.get('manual', ''))}</span>"),
        ("predictor", "predictor", _e(plan.get("predictor", NONE))),
        ("builds", "builds", f"{len(builds)} <span class='dim'>({len(builds) - 1} submodules "
         "and the main model)</span>"),
        ("steps", "steps", str(len(steps))),
        ("components", "components", str(total)),
        ("placed", "placed", f"{placed} of {total}"),
        ("accuracy", "accuracy", accuracy),
        ("exact", "built exactly right", exact),
        ("cameras", "cameras", _e(cameras)),
        ("flagged", "flagged steps", flagged),
        ("seconds", "prediction time", f"{seconds:.1f} s"),
    ]  # fmt: skip
    items = "".join(
        f"<div data-key='{key}'><dt>{label}</dt><dd>{value}</dd></div>"
        for key, label, value in rows
    )
    return f"<section id='summary'><h2>Summary</h2><dl class='summary'>{items}</dl></section>"


def _contents(builds: list[tuple[str, str, Build, list[dict]]]) -> str:
    groups = []
    for anchor, label, _, steps in builds:
        links = "".join(
            f"<a href='#{_step_id(anchor, s)}' class='st {_status(s)}"
            f"{' flagged' if _flagged(s) else ''}' title='step {_e(s.get('index'))}: "
            f"{_status(s)}'>{_e(s.get('index'))}</a>"
            for s in steps
        )
        groups.append(
            f"<li><span class='build'>{_e(label.split(' (')[0])}</span>"
            f"<div class='steps'>{links}</div></li>"
        )
    legend = (
        "<p class='legend'><span class='st right'>right</span> <span class='st wrong'>wrong</span> "
        "<span class='st failed'>not placed</span> <span class='st placed'>placed</span> "
        "<span class='st placed flagged'>flagged</span><br>keys: j / k next / previous step</p>"
    )
    return f"<nav id='contents'><h2>Steps</h2><ul>{''.join(groups)}</ul>{legend}</nav>"


def _camera_html(s: dict[str, Any]) -> str:
    if "camera" not in s:
        return NONE
    src = s.get("camera_source") or NONE
    if s.get("camera") is None:
        why = s.get("camera_failure") or "no camera"
        return f"<span class='bad'>none</span> ({_e(src)}: {_e(why)})"
    cam = s["camera"]
    how = f", {s['camera_how']}" if s.get("camera_how") else ""
    fit = f", fit {value_html(s['camera_fit'])}" if s.get("camera_fit") is not None else ""
    view = (
        f"elevation {value_html(cam.get('elevation'))}°, azimuth {value_html(cam.get('azimuth'))}°, "
        f"scale {value_html(cam.get('scale'))}"
    )
    return f"{_e(src)}{_e(how)}{fit} <span class='dim'>({view})</span>"


def _component_rows(s: dict[str, Any]) -> str:
    rows = []
    for j, c in enumerate(_components(s)):
        colour = c.get("colour")
        swatch = ""
        if isinstance(colour, int):
            r, g, b = _bg.colour_rgb(colour)
            swatch = f"<span class='swatch' style='background:rgb({r},{g},{b})'></span>"
        if _placed(c):
            ldu = c.get("ldu") or {}
            position = value_html(ldu.get("position"))
            matrix = value_html(ldu.get("matrix")) if isinstance(ldu.get("matrix"), list) else ""
            pose = (
                f"<td class='num'>{value_html(c.get('yaw'))}</td>"
                f"<td class='num'>({value_html(c['lattice'])})</td>"
                f"<td class='num' title='matrix {_e(matrix)}'>({position})</td>"
            )
        else:
            pose = "<td colspan='3' class='bad'>not placed</td>"
        correct = c.get("correct")
        verdict = {True: "<span class='good'>yes</span>", False: "<span class='bad'>no</span>"}
        extra = {k: v for k, v in c.items() if k not in _COMPONENT_SHOWN}
        note = _e(c["failure"]) if c.get("failure") else ""
        if extra:
            note += value_html(extra)
        rows.append(
            f"<tr class='{'unplaced' if not _placed(c) else ''}'><td class='num'>{j + 1}</td>"
            f"<td>{_e(_component_name(c))}</td><td>{swatch}{value_html(colour)}</td>{pose}"
            f"<td>{value_html(c.get('attach'))}</td><td class='num'>{value_html(c.get('confidence'))}</td>"
            f"<td>{verdict.get(correct, NONE) if isinstance(correct, bool) else NONE}</td>"
            f"<td class='note'>{note}</td></tr>"
        )
    if not rows:
        return "<tr><td colspan='10' class='dim'>no components in this step</td></tr>"
    return "".join(rows)


def alternatives_html(s: dict[str, Any]) -> str:
    """A step's ``alternatives`` (plan.json) as lines a reader follows: per solution, each
    component it places otherwise by its row in the step's table (#, from 1), its part, yaw and
    lattice place; what is not well formed is shown as it is."""
    comps = _components(s)
    lines = []
    for alt in s.get("alternatives") or []:
        parts = []
        for x in alt if isinstance(alt, list) else [alt]:
            j = x.get("index") if isinstance(x, dict) else None
            if not isinstance(j, int) or not 0 <= j < len(comps) or x.get("lattice") is None:
                parts.append(value_html(x))
                continue
            parts.append(
                f"#{j + 1} {_e(_component_name(comps[j]))}: yaw "
                f"{value_html(x.get('yaw'))} at ({value_html(x['lattice'])})"
            )
        lines.append("<li>" + "; ".join(parts) + "</li>")
    return f"<ul>{''.join(lines)}</ul>" if lines else NONE


def _figure(p: Picture) -> str:
    if p.uri is not None:
        shown = f"<img src='{p.uri}' alt='{_e(p.caption)}'>"
    else:
        shown = f"<div class='missing'>{_e(p.missing)}</div>"
    return f"<figure>{shown}<figcaption>{_e(p.caption)}</figcaption></figure>"


def _step_section(
    sid: str,
    label: str,
    n_steps: int,
    s: dict[str, Any],
    pictures: list[Picture],
    prev_id: str | None,
    next_id: str | None,
) -> str:
    status = _status(s)
    nav = " · ".join(
        [
            f"<a href='#{prev_id}' rel='prev'>← previous</a>"
            if prev_id
            else "<span>← previous</span>",
            "<a href='#summary'>top</a>",
            f"<a href='#{next_id}' rel='next'>next →</a>" if next_id else "<span>next →</span>",
        ]
    )
    figures = "".join(_figure(p) for p in pictures)
    facts = [("camera", _camera_html(s))]
    facts += [(k, value_html(s.get(k))) for k in STEP_FIELDS]
    if s.get("alternatives"):
        facts.append(("alternatives no picture tells apart", alternatives_html(s)))
    facts += [(k, value_html(v)) for k, v in s.items() if k not in _STEP_SHOWN | _CAMERA_KEYS]
    facts.append(("prediction time", f"{float(s.get('seconds') or 0.0):.2f} s"))
    dl = "".join(f"<div data-key='{_e(k)}'><dt>{_e(k)}</dt><dd>{v}</dd></div>" for k, v in facts)
    flag = " <span class='flag'>⚑ flagged</span>" if _flagged(s) else ""
    return (
        f"<section class='step {status}' id='{_e(sid)}' data-step='{_e(s.get('index'))}'>"
        f"<header><h3>{_e(label)} · step {_e(s.get('index'))} of {n_steps}{flag}</h3>"
        f"<span class='badge {status}'>{status}</span><span class='nav'>{nav}</span></header>"
        f"<div class='figures'>{figures}</div><dl class='facts'>{dl}</dl>"
        "<table class='components'><thead><tr><th>#</th><th>component</th><th>colour</th>"
        "<th>yaw</th><th>lattice (x, y, z)</th><th>LDU (x, y, z)</th><th>attach</th>"
        f"<th>confidence</th><th>right</th><th>note</th></tr></thead><tbody>{_component_rows(s)}"
        "</tbody></table></section>"
    )


_CSS = """
:root { --fg:#1d2330; --dim:#6b7280; --line:#e3e6ea; --good:#1f8a4c; --bad:#c62f3b;
  --warn:#d48806; --accent:#8a2be2; --bg:#f6f7f9; }
* { box-sizing: border-box; }
body { margin:0; font:14px/1.45 system-ui,-apple-system,"Segoe UI",Roboto,sans-serif;
  color:var(--fg); background:var(--bg); }
.page { display:grid; grid-template-columns:230px minmax(0,1fr); gap:24px; max-width:1280px;
  margin:0 auto; padding:16px 24px 48px; }
h1 { grid-column:1 / -1; font-size:20px; margin:8px 0 0; } h2 { font-size:15px; margin:0 0 8px; }
h3 { font-size:15px; margin:0; }
#contents { position:sticky; top:12px; align-self:start; max-height:calc(100vh - 24px);
  overflow:auto; background:#fff; border:1px solid var(--line); border-radius:8px; padding:12px; }
#contents ul { list-style:none; margin:0; padding:0; }
#contents li { margin:0 0 10px; } .build { display:block; font-weight:600; margin-bottom:4px; }
.steps { display:flex; flex-wrap:wrap; gap:4px; }
.st { display:inline-block; min-width:26px; padding:1px 4px; text-align:center; border-radius:4px;
  text-decoration:none; color:#fff; font-size:12px; font-variant-numeric:tabular-nums; }
.st.right { background:var(--good); } .st.wrong { background:var(--bad); }
.st.failed { background:#7a1f27; } .st.placed { background:#5b6b82; }
.st.flagged { outline:2px solid var(--warn); outline-offset:1px; }
.legend { color:var(--dim); font-size:12px; line-height:2; margin:8px 0 0; }
main > section { background:#fff; border:1px solid var(--line); border-radius:8px;
  padding:14px 16px; margin-bottom:16px; scroll-margin-top:8px; }
section.step:target { border-color:var(--accent); box-shadow:0 0 0 2px #8a2be233; }
dl.summary { display:grid; grid-template-columns:repeat(auto-fill,minmax(220px,1fr)); gap:8px 20px;
  margin:0; }
dl.summary dt, dl.facts dt { color:var(--dim); font-size:12px; } dd { margin:0; }
dl.summary dd { font-size:15px; font-weight:600; } .dim { color:var(--dim); font-weight:400; }
dl.summary .dim { display:block; font-size:11px; word-break:break-all; }
section.step header { display:flex; flex-wrap:wrap; align-items:center; gap:10px; margin-bottom:10px; }
.nav { margin-left:auto; color:var(--dim); } .nav a { color:var(--accent); text-decoration:none; }
.badge { font-size:11px; text-transform:uppercase; letter-spacing:.04em; padding:2px 6px;
  border-radius:4px; color:#fff; background:#5b6b82; }
.badge.right { background:var(--good); } .badge.wrong, .badge.failed { background:var(--bad); }
.flag { color:var(--warn); font-size:13px; }
.figures { display:flex; flex-wrap:wrap; gap:12px; }
figure { margin:0; width:256px; } figure img, .missing { width:256px; height:256px;
  border:1px solid var(--line); border-radius:4px; background:#fff; image-rendering:auto; }
.missing { display:flex; align-items:center; justify-content:center; text-align:center;
  color:var(--dim); padding:12px; background:repeating-linear-gradient(45deg,#fafafa 0 8px,#f0f1f3 8px 16px); }
figcaption { color:var(--dim); font-size:12px; margin-top:2px; }
dl.facts { display:grid; grid-template-columns:repeat(auto-fill,minmax(200px,1fr)); gap:6px 16px;
  margin:12px 0; } dl.facts > div[data-key=camera] { grid-column:1 / -1; }
table.components { border-collapse:collapse; width:100%; font-size:13px; }
.components th { text-align:left; color:var(--dim); font-weight:500; border-bottom:1px solid var(--line);
  padding:4px 6px; white-space:nowrap; } .components td { border-bottom:1px solid var(--line); padding:4px 6px; }
td.num { font-variant-numeric:tabular-nums; white-space:nowrap; } tr.unplaced td { background:#fdf1f2; }
td.note { color:var(--dim); } .good { color:var(--good); font-weight:600; }
.bad { color:var(--bad); font-weight:600; } .error { color:var(--bad); }
.swatch { display:inline-block; width:11px; height:11px; border-radius:2px; margin-right:5px;
  vertical-align:-1px; border:1px solid #0003; }
dl.kv { display:grid; grid-template-columns:auto 1fr; gap:0 8px; margin:0; } dl.kv dt { color:var(--dim); }
ul { margin:0; padding-left:18px; } main.wide { grid-column:1 / -1; }
@media (max-width:800px) { .page { grid-template-columns:1fr; } #contents { position:static; } }
"""

#: j / k (or n / p) jump to the next / previous step.
_JS = """
document.addEventListener('keydown', function (e) {
  if (e.ctrlKey || e.metaKey || e.altKey) return;
  var d = {j: 1, n: 1, k: -1, p: -1}[e.key];
  if (!d) return;
  var steps = Array.prototype.slice.call(document.querySelectorAll('section.step'));
  var here = -1;
  steps.forEach(function (s, i) { if (s.getBoundingClientRect().top <= 12) here = i; });
  var to = steps[Math.min(Math.max(here + d, 0), steps.length - 1)];
  if (to) { location.hash = to.id; }
});
"""


def _page(title: str, main: str, contents: str = "") -> str:
    """The whole document: the contents beside the main column."""
    wide = "" if contents else " class='wide'"
    return (
        "<!DOCTYPE html>\n<html lang='en'><head><meta charset='utf-8'>"
        "<meta name='viewport' content='width=device-width, initial-scale=1'>"
        f"<title>{_e(title)}</title><style>{_CSS}</style></head><body>"
        f"<div class='page'><h1>{_e(title)}</h1>{contents}<main{wide}>{main}</main></div>"
        f"<script>{_JS}</script></body></html>\n"
    )
