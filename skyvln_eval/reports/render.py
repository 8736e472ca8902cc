"""Headless, deterministic figure output.

Figures are built as :class:`~skyvln_eval.reports.report_figure.ReportFigure` objects (a
matplotlib Figure that Jupyter shows as a PNG) with the Agg canvas, so no display and no
pyplot global state are involved. :func:`save_figure` strips the metadata
that changes between runs (creation dates, software versions), so identical inputs give
byte-identical PNG, PDF and SVG files.

matplotlib is imported when the first figure is made, not with the package: the
command line (and every worker process a run spawns, which imports it again) starts
about 0.5 s sooner.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from skyvln_eval.errors import ConfigError
from skyvln_eval.fileio import atomic_write_bytes

if TYPE_CHECKING:
    from matplotlib.figure import Figure

FIGURE_FORMATS = ("png", "pdf", "svg")

_METADATA: dict[str, dict[str, str | None]] = {
    "png": {"Software": None},
    "pdf": {"Creator": None, "Producer": None, "CreationDate": None, "ModDate": None},
    "svg": {"Creator": None, "Date": None},
}


def new_figure(width_in: float, height_in: float) -> Figure:
    """A figure on the Agg canvas (works without a display; shown as a PNG in Jupyter)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    from skyvln_eval.reports.report_figure import ReportFigure

    figure = ReportFigure(figsize=(width_in, height_in), dpi=100, layout="constrained")
    FigureCanvasAgg(figure)
    return figure


def save_figure(figure: Figure, path: str | Path, dpi: int = 150) -> Path:
    """Write ``figure`` atomically; the format comes from the suffix (png, pdf or svg)."""
    path = Path(path)
    fmt = path.suffix.lstrip(".").lower()
    if fmt not in FIGURE_FORMATS:
        raise ConfigError(f"{path}: unknown figure format {fmt!r}; use one of {FIGURE_FORMATS}")
    atomic_write_bytes(path, figure_bytes(figure, fmt, dpi))
    return path


def figure_bytes(figure: Figure, fmt: str, dpi: int) -> bytes:
    """``figure`` encoded as ``fmt`` (png, pdf or svg), the same bytes for the same figure."""
    import io

    import matplotlib

    buffer = io.BytesIO()
    # SVG ids are random unless salted; a fixed salt makes them repeatable.
    with matplotlib.rc_context({"svg.hashsalt": "skyvln-eval", "svg.fonttype": "path"}):
        figure.savefig(buffer, format=fmt, dpi=dpi, metadata=_METADATA[fmt])
    return buffer.getvalue()
