"""``python -m skyvln_eval``: the ``skyvln-eval`` command, for an environment whose scripts
folder is not on PATH."""

from skyvln_eval.cli import main

main()
