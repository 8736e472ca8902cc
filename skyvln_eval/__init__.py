"""skyvln-eval: dataset and evaluation toolkit for aerial vision-and-language navigation.

Importing this package imports no optional heavy dependency (openai, ray, transformers,
torch); sub-packages are imported on use: ``skyvln_eval.avdn``, ``skyvln_eval.worlds``, ...
"""

from skyvln_eval.errors import SkyvlnError

__version__ = "0.1.0"

__all__ = ["SkyvlnError", "__version__"]
