"""Write ``report.html`` for a mission, stage or campaign folder (:func:`write_report`).

The page is rendered by a Jinja2 template (``templates/report.html.j2``, autoescaped) with its CSS inline and every
figure a ``data:image/png;base64`` URI, so it needs nothing but the file: no script, font, style sheet or image is
fetched (the tests open it in a headless Chromium and count the requests). It is written atomically.
"""

from __future__ import annotations

import base64
import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from oacli import __version__
from oacli.io.atomic import write_text_atomic
from oacli.report.folder import folder_kind, read_png, read_summary

REPORT_NAME = "report.html"


@dataclass(frozen=True)
class ReportResult:
    """A written report.

    Attributes
    ----------
    path : Path
        ``report.html``.
    kind : str
        ``mission``, ``stage`` or ``campaign``.
    size_bytes : int
    wall_time_s : float
        Time to read the folder and write the page [s].
    figures : int
        Figures embedded.
    """

    path: Path
    kind: str
    size_bytes: int
    wall_time_s: float
    figures: int


def fmt(value: Any, digits: int = 3) -> str:
    """A number with ``digits`` significant digits (— for None, 'never' for +inf); other values as text."""
    if value is None:
        return "—"
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if math.isinf(value):
            return "never" if value > 0 else "−∞"
        if math.isnan(value):
            return "—"
        if value != 0 and (abs(value) >= 1e5 or abs(value) < 1e-3):
            return f"{value:.{digits}g}"
        return f"{value:.{digits}g}" if abs(value) < 10 ** digits else f"{value:.0f}"
    return str(value)


def data_uri(png: bytes) -> str:
    """``data:image/png;base64,...`` of PNG bytes."""
    return "data:image/png;base64," + base64.b64encode(png).decode("ascii")


def stage_context(folder: Path, summary: dict[str, Any]) -> dict[str, Any]:
    """A single stage's page: status, its scalar results, its PNGs (``summary.json`` ``files``), its config.

    Parameters
    ----------
    folder : Path
    summary : dict

    Returns
    -------
    dict
    """
    scalars = [(k, v) for k, v in summary.items()
               if isinstance(v, int | float | str | bool) and k not in ("status", "stage", "error")]
    figures = []
    for role, rel in (summary.get("files") or {}).items():
        if isinstance(rel, str) and rel.endswith(".png") and (folder / rel).is_file():
            figures.append({"id": role, "title": role.removeprefix("png_").replace("_", " "), "caption": "",
                            "png": read_png(folder / rel), "source": rel})
    config = folder / "config.yaml"
    rrd = next(iter(sorted(folder.glob("*.rrd"))), None)
    return {"kind": "stage", "title": f"{summary.get('stage', 'stage')} {folder.name}", "summary": summary,
            "complete": True, "scalars": scalars, "figures": figures,
            "config_text": config.read_text() if config.is_file() else None,
            "files": {"folder": str(folder.resolve()), "recording": None if rrd is None else str(rrd.resolve())},
            "commands": {}}


def build_context(folder: Path) -> dict[str, Any]:
    """The page's content for ``folder`` (whatever its kind).

    Parameters
    ----------
    folder : Path

    Returns
    -------
    dict

    Raises
    ------
    InputError
        Bad input (:mod:`oacli.report.folder`).
    """
    kind = folder_kind(folder)
    if kind == "campaign":
        from oacli.report.campaign import campaign_context

        return campaign_context(folder)
    summary = read_summary(folder)
    if kind == "mission":
        from oacli.report.mission import mission_context

        return mission_context(folder, summary)
    return stage_context(folder, summary)


def render(context: dict[str, Any]) -> str:
    """The HTML page of a context (:func:`build_context`).

    Parameters
    ----------
    context : dict

    Returns
    -------
    str
    """
    import jinja2

    env = jinja2.Environment(loader=jinja2.PackageLoader("oacli.report", "templates"),
                             autoescape=jinja2.select_autoescape(default=True, default_for_string=True),
                             trim_blocks=True, lstrip_blocks=True)
    env.filters["fmt"] = fmt
    env.filters["data_uri"] = data_uri
    return env.get_template("report.html.j2").render(**context, version=__version__)


def write_report(folder: Path, out: Path | None = None) -> ReportResult:
    """Read ``folder`` and write its report (module docstring).

    Parameters
    ----------
    folder : Path
        A mission, stage or campaign folder.
    out : Path, optional
        Where to write (default ``folder/report.html``).

    Returns
    -------
    ReportResult

    Raises
    ------
    InputError
        Bad input: not a run folder, no summary, a cut MCAP or PNG (one line).
    """
    start = time.perf_counter()
    folder = Path(folder)
    context = build_context(folder)
    context["generated"] = {"utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())}
    html = render(context)
    path = Path(out) if out is not None else folder / REPORT_NAME
    write_text_atomic(path, html)
    return ReportResult(path=path, kind=context["kind"], size_bytes=len(html.encode()),
                        wall_time_s=time.perf_counter() - start, figures=len(context["figures"]))


__all__ = ["REPORT_NAME", "ReportResult", "build_context", "data_uri", "fmt", "render", "write_report"]
