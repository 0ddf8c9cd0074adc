"""The report builder: ``report.md``, PNG figures and ``results.json`` in one directory.

Build the Markdown in order with :meth:`Report.heading`, :meth:`Report.text`,
:meth:`Report.table`, :meth:`Report.figure`; put every number worth keeping
in :attr:`Report.results` (a nested dict, written to ``results.json``);
record pass/fail physics checks with :meth:`Report.check` and the comparison
with the thesis with :meth:`Report.thesis`.  :meth:`Report.write` adds the
"Checks" and "Comparison with the thesis" sections at the end and writes
the files.  Figures are drawn on :class:`matplotlib.figure.Figure` with the
Agg canvas (no pyplot state, no display).
"""

from __future__ import annotations

import json
import math
import os
import re
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from controller.record import to_jsonable

if TYPE_CHECKING:
    from workbench.checks.result import CheckResult

__all__ = ["Check", "KnownLimit", "Report", "fmt", "new_figure"]


def new_figure(width_in: float = 7.5, height_in: float = 4.5, dpi: int = 110) -> Figure:
    """A matplotlib Figure on the Agg canvas (use ``fig.add_subplot``/``fig.subplots``)."""
    fig = Figure(figsize=(width_in, height_in), dpi=dpi, layout="constrained")
    FigureCanvasAgg(fig)
    return fig


COST_HEADERS: tuple[str, ...] = ("link 1 vel (in/s)", "%", "link 2 vel (in/s)", "%", "link 1 acc (in/s²)", "%", "link 2 acc (in/s²)", "%")
"""The columns of a cost table (§4.2.1): RMS deflection velocity and acceleration per link, each with its % of a reference."""


def cost_cells(entry: Any, velocity_pct: str = "velocity_pct", acceleration_pct: str = "acceleration_pct") -> list[Any]:
    """A cost table's cells for one run (:data:`COST_HEADERS`), from its entry's
    ``velocity_rms_in_s``, ``acceleration_rms_in_s2`` and the two % keys."""
    v, a, vp, ap = entry["velocity_rms_in_s"], entry["acceleration_rms_in_s2"], entry[velocity_pct], entry[acceleration_pct]
    return [v[0], vp[0], v[1], vp[1], a[0], ap[0], a[1], ap[1]]


def fmt(value: Any, digits: int = 4) -> str:
    """A number for a Markdown table: ``digits`` significant digits, '–' for None/NaN."""
    if value is None:
        return "–"
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, int):
        return str(value)
    try:
        v = float(value)
    except (TypeError, ValueError):
        return str(value)
    if math.isnan(v):
        return "–"
    if math.isinf(v):
        return "∞" if v > 0 else "−∞"
    if v == 0.0:
        return "0"
    if 1e-3 <= abs(v) < 1e5:
        return f"{v:.{digits}g}"
    return f"{v:.{max(1, digits - 1)}e}"


@dataclass(frozen=True)
class Check:
    """A pass/fail statement the experiment's numbers must satisfy."""

    name: str
    passed: bool
    detail: str = ""


@dataclass(frozen=True)
class ThesisComparison:
    """One line of "what the thesis reports" against what this run found."""

    claim: str
    observed: str
    agrees: bool | str | None = None
    """True/False, a word such as ``"partly"``, or None where the comparison is not a yes/no."""


@dataclass(frozen=True)
class KnownLimit:
    """A goal the experiment measures that this build does not always reach.

    Reported against the goal in its own section, never a pass/fail check: the
    experiment's checks hold the figure the build reached, with a stated margin,
    so a run fails only when the build regresses."""

    goal: str
    measured: str
    met: bool


class Report:
    """Collects Markdown, figures, results and checks; :meth:`write` puts them in ``out_dir``."""

    def __init__(self, out_dir: str | Path, title: str, name: str = "", section: str = "", description: str = "") -> None:
        self.out_dir = Path(out_dir)
        self.out_dir.mkdir(parents=True, exist_ok=True)
        self.title = title
        self.name = name
        self.section = section
        self.description = description
        self.results: dict[str, Any] = {}
        """Everything numeric worth keeping; written to ``results.json`` under ``"results"``."""
        self.checks: list[Check] = []
        self.comparisons: list[ThesisComparison] = []
        self.known_limits: list[KnownLimit] = []
        self.figures: list[str] = []
        self.attachments: list[dict[str, str]] = []
        self.meta: dict[str, Any] = {}
        self.service_warnings: dict[str, dict[str, Any]] = {}
        """The rig's log warnings during the runs, by kind: count and first message (the runner fills it, :mod:`workbench.service_warnings`)."""
        self._body: list[str] = []

    # -- content --------------------------------------------------------------------------
    def heading(self, text: str, level: int = 2) -> Report:
        """A Markdown heading (level 2 by default; the title is the only level 1)."""
        if not 1 <= level <= 6:
            raise ValueError("heading level must be 1..6")
        self._body += ["", "#" * level + " " + text, ""]
        return self

    def text(self, *paragraphs: str) -> Report:
        """Paragraphs of Markdown."""
        for p in paragraphs:
            self._body += [p.strip(), ""]
        return self

    def bullets(self, items: Sequence[str]) -> Report:
        self._body += [f"- {item}" for item in items] + [""]
        return self

    def code(self, text: str, lang: str = "") -> Report:
        self._body += [f"```{lang}", text.rstrip("\n"), "```", ""]
        return self

    def table(
        self,
        headers: Sequence[str],
        rows: Sequence[Sequence[Any]],
        caption: str | None = None,
        align: str | None = None,
        digits: int = 4,
    ) -> Report:
        """A Markdown table; numbers are formatted with :func:`fmt` (strings are kept as given).

        ``align``: one of 'l', 'r', 'c' per column (default: right for numeric columns, left otherwise).
        """
        if any(len(r) != len(headers) for r in rows):
            raise ValueError("every row needs one cell per header")
        if align is None:  # numbers right, text left
            align = "".join("r" if rows and all(not isinstance(r[i], str) or r[i] in ("–", "") for r in rows) else "l" for i in range(len(headers)))
        marks = {"l": "---", "r": "---:", "c": ":---:"}
        if caption:
            self._body += [f"*{caption}*", ""]
        self._body.append("| " + " | ".join(_cell(str(h)) for h in headers) + " |")
        self._body.append("| " + " | ".join(marks[a] for a in align) + " |")
        for r in rows:
            cells = [_cell(c) if isinstance(c, str) else fmt(c, digits) for c in r]
            self._body.append("| " + " | ".join(cells) + " |")
        self._body.append("")
        return self

    def figure(self, fig: Figure, filename: str, caption: str = "") -> Path:
        """Save ``fig`` as ``out_dir/filename`` (PNG) and embed it in the report."""
        if not filename.endswith(".png"):
            filename += ".png"
        path = self.out_dir / filename
        path.parent.mkdir(parents=True, exist_ok=True)
        fig.savefig(path, format="png", metadata={"Software": None})
        self.figures.append(filename)
        alt = caption.rstrip(".").replace("[", "(").replace("]", ")") if caption else filename
        self._body += [f"![{alt}]({filename})", ""]
        if caption:
            self._body += [f"*{caption}*", ""]
        return path

    def attach(self, path: str | Path, description: str) -> Report:
        """List a file the experiment wrote (a run record, raw data) in the report and results.json."""
        p = Path(path)
        try:  # relative to the report, whether the paths came absolute or relative to the working directory
            rel = os.path.relpath(p.resolve(), Path(self.out_dir).resolve())  # "../x" for a file beside the folder
        except ValueError:  # another drive (Windows): no relative path exists
            rel = str(p)
        self.attachments.append({"path": Path(rel).as_posix(), "description": description})
        return self

    def check(self, name: str, passed: bool, detail: str = "") -> bool:
        """Record a physics/consistency check; returns ``passed``."""
        self.checks.append(Check(name, bool(passed), detail))
        return bool(passed)

    def signal_check(self, result: CheckResult, name: str = "", *, figure: str = "") -> bool:
        """Record a signal check (:mod:`workbench.checks`) as one of this report's checks: its
        one-line measurement against its limit is the detail (an INVALID check, which compared
        nothing, fails); with ``figure`` (a file name) its figure joins the report."""
        if figure:
            self.figure(result.figure(), figure, caption=result.line())
        return self.check(name or result.name, result.passed, result.explain())

    def check_every(self, name: str, outcomes: Iterable[bool], detail: str = "", *, at_least: int = 1, also: bool = True) -> bool:
        """A check that holds for every item of a set judged over at least ``at_least`` items (and
        ``also``): "k of n" leads its detail, and a set of fewer items fails as too few to judge,
        never passes on nothing."""
        judged = [bool(x) for x in outcomes]
        counted = f"{sum(judged)} of {len(judged)}"
        if len(judged) < at_least:
            counted = f"too few to judge: {len(judged)} (at least {at_least})"
        return self.check(name, len(judged) >= at_least and all(judged) and also, counted + (f"; {detail}" if detail else ""))

    def thesis(self, claim: str, observed: str, agrees: bool | str | None = None) -> Report:
        """One row of the comparison with what the thesis reports (qualitatively)."""
        self.comparisons.append(ThesisComparison(claim, observed, agrees))
        return self

    def known_limit(self, goal: str, measured: str, met: bool) -> Report:
        """One row of the known limits: a goal out of this build's reach, with what this run measured."""
        self.known_limits.append(KnownLimit(goal, measured, bool(met)))
        return self

    def set_meta(self, **meta: Any) -> None:
        """Run metadata (the runner sets seed, mode, quick, runtime)."""
        self.meta.update(meta)

    # -- output ---------------------------------------------------------------------------
    def markdown(self) -> str:
        m = self.meta
        lines = [f"# {self.title}", ""]
        info = []
        if self.name:
            info.append(f"`ralf-hil experiment {self.name}`")
        if self.section:
            info.append(f"thesis {self.section}")
        if m:
            info.append(
                f"seed {m.get('seed', '–')}, {'quick' if m.get('quick') else 'full'} run"
                + (f", mode {m['mode']}" if m.get("needs_rig") else "")
                + (f", {m['runtime_s']:.1f} s" if "runtime_s" in m else "")
            )
        if info:
            lines += [" · ".join(info), ""]
        if self.description:
            lines += [f"> {self.description}", ""]
        lines += self._body
        if self.comparisons:
            lines += ["", "## Comparison with the thesis", ""]
            lines += ["| the thesis reports | this run | agrees |", "| --- | --- | :---: |"]
            for c in self.comparisons:
                if isinstance(c.agrees, str):
                    mark = c.agrees
                else:
                    mark = "–" if c.agrees is None else ("yes" if c.agrees else "**no**")
                lines.append(f"| {_cell(c.claim)} | {_cell(c.observed)} | {mark} |")
            lines.append("")
        if self.known_limits:
            lines += ["", "## Known limits", ""]
            lines += [
                "Goals measured here that this build does not reach in every run; they are reported, not checked. "
                "The checks below hold what the build reached, each with its margin.",
                "",
            ]
            lines += ["| goal | this run | met |", "| --- | --- | :---: |"]
            lines += [f"| {_cell(k.goal)} | {_cell(k.measured)} | {'yes' if k.met else 'no'} |" for k in self.known_limits]
            lines.append("")
        if self.checks:
            passed = sum(chk.passed for chk in self.checks)
            lines += ["", "## Checks", "", f"{passed} of {len(self.checks)} passed.", ""]
            lines += ["| check | result | detail |", "| --- | :---: | --- |"]
            for chk in self.checks:
                lines.append(f"| {_cell(chk.name)} | {'pass' if chk.passed else '**FAIL**'} | {_cell(chk.detail)} |")
            lines.append("")
        if self.service_warnings:
            lines += ["", "## Warnings from the rig", ""]
            lines += [
                "Warnings the rig's services logged during this experiment's runs (a monitor firing, a DSP batch over its compute budget), "
                "counted here instead of printed; the checks above judge the runs.",
                "",
            ]
            lines += ["| kind | count | first message |", "| --- | ---: | --- |"]
            lines += [f"| {_cell(kind)} | {w['count']} | {_cell(w['first'])} |" for kind, w in self.service_warnings.items()]
            lines.append("")
        if self.attachments:
            lines += ["", "## Files", ""]
            lines += [f"- [`{a['path']}`]({a['path']}): {a['description']}" for a in self.attachments]
            lines.append("")
        text = "\n".join(lines)
        while "\n\n\n" in text:
            text = text.replace("\n\n\n", "\n\n")
        return text.strip() + "\n"

    def as_json(self) -> dict[str, Any]:
        return {
            "experiment": self.name,
            "title": self.title,
            "section": self.section,
            "meta": to_jsonable(self.meta),
            "results": to_jsonable(self.results),
            "checks": [{"name": c.name, "passed": c.passed, "detail": c.detail} for c in self.checks],
            **({"known_limits": [{"goal": k.goal, "measured": k.measured, "met": k.met} for k in self.known_limits]} if self.known_limits else {}),
            "thesis_comparison": [{"claim": c.claim, "observed": c.observed, "agrees": c.agrees} for c in self.comparisons],
            "figures": list(self.figures),
            "attachments": list(self.attachments),
            **({"service_warnings": self.service_warnings} if self.service_warnings else {}),
        }

    def write(self) -> tuple[Path, Path]:
        """Write ``report.md`` and ``results.json``; returns their paths."""
        report = self.out_dir / "report.md"
        results = self.out_dir / "results.json"
        report.write_text(self.markdown(), encoding="utf-8")
        results.write_text(json.dumps(self.as_json(), indent=2, allow_nan=False) + "\n", encoding="utf-8")
        return report, results


def _cell(text: str) -> str:
    """Text safe inside a Markdown table cell: pipes escaped (once), no newlines."""
    return re.sub(r"(?<!\\)\|", r"\\|", text).replace("\n", " ")
