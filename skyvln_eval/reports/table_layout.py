"""Which rows, in which order, with which notes, `reproduce` put in each table.

A scores file holds every system a reproduction scored: Table I's rows and Table II's
backends side by side (the rule-backend row of Table II is the same episodes as Table I's
Full row). From the scores alone `skyvln-eval table` cannot tell which rows belong to
which table, nor their order: so `reproduce` writes ``tables.json`` next to
``scores.csv``, and `table` given that scores file (and no ``--row``) makes the tables
`reproduce` made, notes and intervals included.
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from skyvln_eval.errors import DataError
from skyvln_eval.fileio import atomic_write_json
from skyvln_eval.metrics.aggregate import CI_UNITS, CiUnit, ci_unit_named

LAYOUT_FILE = "tables.json"
LAYOUT_FORMAT = "skyvln-eval.table-layout"
LAYOUT_VERSION = 1


@dataclass(frozen=True)
class TableLayout:
    """One table as `reproduce` made it: its rows in order, the caller's notes and, where
    they are not the table's own (a plan's Table II over another split), its splits."""

    rows: tuple[str, ...]
    notes: tuple[str, ...]
    splits: tuple[str, ...] = ()


@dataclass(frozen=True)
class ReproducedTables:
    """Every table's layout, and what its intervals and cells were made with."""

    tables: Mapping[str, TableLayout]
    resamples: int
    seed: int
    withheld: tuple[str, ...]
    ci_unit: CiUnit = "episode"


def write_layout(scores_dir: Path, layout: ReproducedTables) -> Path:
    """``tables.json`` in ``scores_dir``, atomically."""
    path = scores_dir / LAYOUT_FILE
    atomic_write_json(
        path,
        {
            "format": LAYOUT_FORMAT,
            "version": LAYOUT_VERSION,
            "resamples": layout.resamples,
            "seed": layout.seed,
            "ci_unit": layout.ci_unit,
            "withheld": list(layout.withheld),
            "tables": {
                name: {"rows": list(t.rows), "notes": list(t.notes)}
                | ({"splits": list(t.splits)} if t.splits else {})
                for name, t in layout.tables.items()
            },
        },
        indent=1,
    )
    return path


def layout_beside(scores_files: Sequence[Path]) -> ReproducedTables | None:
    """The layout `reproduce` wrote next to the one scores file given, if any; none for
    several files (their systems may come from different reproductions)."""
    if len(scores_files) != 1:
        return None
    path = Path(scores_files[0]).parent / LAYOUT_FILE
    if not path.is_file():
        return None
    return read_layout(path)


def read_layout(path: Path) -> ReproducedTables:
    """A ``tables.json``; a damaged one is refused, naming the file and field."""
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as error:
        raise DataError(f"{path}: not a readable table layout ({error})") from error
    if not isinstance(data, dict) or data.get("format") != LAYOUT_FORMAT:
        raise DataError(f"{path}: field 'format' is not {LAYOUT_FORMAT!r}")
    if data.get("version") != LAYOUT_VERSION:
        raise DataError(
            f"{path}: field 'version' is {data.get('version')!r}; this toolkit reads "
            f"version {LAYOUT_VERSION}"
        )
    tables = data.get("tables")
    if not isinstance(tables, dict):
        raise DataError(f"{path}: field 'tables' must be an object")
    return ReproducedTables(
        tables={name: _table(path, name, value) for name, value in tables.items()},
        resamples=_integer(path, "resamples", data.get("resamples")),
        seed=_integer(path, "seed", data.get("seed")),
        withheld=_strings(path, "withheld", data.get("withheld")),
        ci_unit=_ci_unit(path, data.get("ci_unit", "episode")),  # older files: episodes
    )


def _table(path: Path, name: str, value: Any) -> TableLayout:
    if not isinstance(value, dict):
        raise DataError(f"{path}: field 'tables.{name}' must be an object")
    return TableLayout(
        rows=_strings(path, f"tables.{name}.rows", value.get("rows")),
        notes=_strings(path, f"tables.{name}.notes", value.get("notes")),
        splits=_strings(path, f"tables.{name}.splits", value.get("splits", [])),
    )


def _strings(path: Path, field: str, value: Any) -> tuple[str, ...]:
    if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
        raise DataError(f"{path}: field '{field}' must be a list of strings")
    return tuple(value)


def _ci_unit(path: Path, value: Any) -> CiUnit:
    unit = ci_unit_named(value)
    if unit is None:
        raise DataError(f"{path}: field 'ci_unit' must be one of {', '.join(CI_UNITS)}")
    return unit


def _integer(path: Path, field: str, value: Any) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < 0:
        raise DataError(f"{path}: field '{field}' must be a non-negative integer")
    return value
