"""The toolkit's figure class: a matplotlib Figure that Jupyter shows as an image.

A bare :class:`~matplotlib.figure.Figure` on the Agg canvas has no representation IPython
can display unless pyplot's inline backend is active (it is not under ``MPLBACKEND=Agg``,
as the test suite runs notebooks, nor after ``matplotlib.use("Agg")``): a notebook showed
``<Figure size 1200x1200 with 13 Axes>``. ``_repr_png_`` renders the PNG from the figure
itself, with no display and no pyplot; IPython calls it only when a figure is displayed.

Imported by :func:`skyvln_eval.reports.render.new_figure`, not with the package, so that
importing the package does not import matplotlib.
"""

from __future__ import annotations

from matplotlib.figure import Figure

from skyvln_eval.reports.render import figure_bytes


class ReportFigure(Figure):
    """A figure that IPython displays as a PNG at the figure's own resolution."""

    def _repr_png_(self) -> bytes:
        # Encoded as save_figure encodes it (no run-dependent metadata), so a re-executed
        # notebook's outputs only change when the figure does.
        return figure_bytes(self, "png", dpi=int(self.dpi))
