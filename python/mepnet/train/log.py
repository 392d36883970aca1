"""Training metrics on disk: ``metrics.csv`` (long format: step, split, name, value; appended),
``metrics.json`` (a list of rows; rewritten atomically) and ``curves.png`` (losses and
validation accuracy against steps)."""

from __future__ import annotations

import csv
import io
import json
import math
import os
from pathlib import Path
from typing import Any

from mepnet.files import atomic_write_bytes, atomic_write_json

CSV_HEADER = ("step", "split", "name", "value")


class MetricsLog:
    """Rows ``{"step": int, "split": "train" | "val", name: value, ...}`` of one run.

    ``keep_until``: on resume, rows logged after the checkpoint's step (by the run that was
    interrupted) are dropped, since the resumed run logs those steps again; None starts empty.
    """

    def __init__(self, out: str | os.PathLike[str], keep_until: int | None = None):
        self.out = Path(out)
        self.rows: list[dict[str, Any]] = []
        path = self.out / "metrics.json"
        if keep_until is not None and path.is_file():
            try:
                rows = json.loads(path.read_text())
            except json.JSONDecodeError:
                rows = []  # torn by a crash cannot happen (atomic), but never fail on metrics
            self.rows = [r for r in rows if isinstance(r, dict) and r.get("step", 0) <= keep_until]
        self._rewrite_csv()
        atomic_write_json(path, self.rows)

    def _rewrite_csv(self) -> None:
        lines = [CSV_HEADER, *(x for r in self.rows for x in _long(r))]
        atomic_write_bytes(self.out / "metrics.csv", _csv_bytes(lines))

    def add(self, row: dict[str, Any]) -> None:
        """Append a row to both files."""
        self.rows.append(row)
        with open(self.out / "metrics.csv", "a", newline="") as f:
            csv.writer(f).writerows(_long(row))
        atomic_write_json(self.out / "metrics.json", self.rows)

    def series(self, split: str, name: str) -> tuple[list[int], list[float]]:
        """Steps and values of one metric (rows without it, or with None, skipped)."""
        pts = [
            (r["step"], float(r[name]))
            for r in self.rows
            if r.get("split") == split and isinstance(r.get(name), (int, float))
        ]
        return [p[0] for p in pts], [p[1] for p in pts]

    def plot(self) -> None:
        """``curves.png``: training loss and its parts (log scale), validation accuracy."""
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.figure import Figure

        fig = Figure(figsize=(11, 4), dpi=100)
        FigureCanvasAgg(fig)
        left, right = fig.subplots(1, 2)
        names = [k for r in self.rows if r.get("split") == "train" for k in r]
        for name in dict.fromkeys(n for n in names if n == "loss" or n.startswith("loss_")):
            x, y = self.series("train", name)
            y = [v if v > 0 and math.isfinite(v) else float("nan") for v in y]
            if x:
                left.plot(x, y, label=name, linewidth=2 if name == "loss" else 1)
        left.set_yscale("log")
        left.set_xlabel("step")
        left.set_title("training loss")
        if left.lines:
            left.legend(fontsize=7)
        for name in ("component_acc", "step_acc"):
            x, y = self.series("val", name)
            if x:
                right.plot(x, y, marker="o", label=name)
        right.set_ylim(0, 1)
        right.set_xlabel("step")
        right.set_title("validation pose accuracy (detector + stage 2)")
        if right.lines:
            right.legend(fontsize=7)
        else:
            right.text(0.5, 0.5, "no validation (--val-dir)", ha="center", va="center")
        fig.tight_layout()
        buf = io.BytesIO()
        fig.savefig(buf, format="png")
        atomic_write_bytes(self.out / "curves.png", buf.getvalue())


def _long(row: dict[str, Any]) -> list[tuple[Any, ...]]:
    return [
        (row["step"], row["split"], k, v)
        for k, v in row.items()
        if k not in ("step", "split") and v is not None
    ]


def _csv_bytes(lines: list[tuple[Any, ...]]) -> bytes:

    buf = io.StringIO()
    csv.writer(buf).writerows(lines)
    return buf.getvalue().encode()
