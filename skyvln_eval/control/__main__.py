"""Record the runs behind the paper's control figures (no CLI framework needed).

    python -m skyvln_eval.control OUT_DIR [--seed 0]

writes ``OUT_DIR/<case>_<controller>.parquet`` for PID, linear MPC and NMPC in the static
and the dynamic obstacle case (:func:`skyvln_eval.control.record_paper_runs`).
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from pathlib import Path

from skyvln_eval.control.recordings import record_paper_runs


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(
        prog="python -m skyvln_eval.control", description="Record the paper's control-figure runs."
    )
    parser.add_argument("out_dir", type=Path)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    for (name, case), path in record_paper_runs(args.out_dir, seed=args.seed).items():
        print(f"{case:8} {name:5} {path}")


if __name__ == "__main__":
    main()
