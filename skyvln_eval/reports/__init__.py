"""Reports: paper-style tables (Markdown, LaTeX, CSV) and headless, deterministic figures.

Tables: :func:`paper_table` makes the SkyVLN paper's Table I (:data:`TABLE_I`) or Table II
(:data:`TABLE_II`) from per-episode scores, the same way for every caller (it summarises
them and arranges the summary with :func:`build_table`); :func:`to_markdown`,
:func:`to_latex` and :func:`to_csv` render it. Figures:
:func:`control_figure` (6-DOF curves and errors per controller, per scenario),
:func:`sr_vs_threshold_figure`, :func:`ne_distribution_figure`,
:func:`trajectory_figure` (views over the map tile); :func:`save_figure` writes them
byte-identically for identical input.
"""

from skyvln_eval.reports.control_figures import control_figure
from skyvln_eval.reports.nav_figures import (
    ne_distribution_figure,
    sr_vs_threshold_figure,
    success_rate_curve,
)
from skyvln_eval.reports.paper_tables import paper_table, table_metrics
from skyvln_eval.reports.render import FIGURE_FORMATS, new_figure, save_figure
from skyvln_eval.reports.tables import (
    TABLE_I,
    TABLE_II,
    TABLES,
    Cell,
    Table,
    TableSpec,
    build_table,
    latex_escape,
    to_csv,
    to_latex,
    to_markdown,
)
from skyvln_eval.reports.trajectory_figure import trajectory_figure, trajectory_labels

__all__ = [
    "FIGURE_FORMATS",
    "TABLES",
    "TABLE_I",
    "TABLE_II",
    "Cell",
    "Table",
    "TableSpec",
    "build_table",
    "control_figure",
    "latex_escape",
    "ne_distribution_figure",
    "new_figure",
    "paper_table",
    "save_figure",
    "sr_vs_threshold_figure",
    "success_rate_curve",
    "table_metrics",
    "to_csv",
    "to_latex",
    "to_markdown",
    "trajectory_figure",
    "trajectory_labels",
]
