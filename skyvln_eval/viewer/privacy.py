"""Rerun's usage analytics, off for every Rerun process the toolkit starts.

The ``rerun`` executable (viewer, web-viewer server, ``rerun rrd``) sends anonymous usage
events unless its analytics config, ``$XDG_CONFIG_HOME/rerun/analytics.json``, says
``analytics_enabled: false`` (what ``rerun analytics disable`` writes). Researchers view
private data with it, so the toolkit starts it with ``XDG_CONFIG_HOME`` pointing at a folder
of its own whose config has analytics off; the user's own Rerun config is left untouched.
The Rerun Python SDK that builds recordings has no analytics. The browser side (the web
viewer also reports usage, checks GitHub for releases and loads web fonts) is closed by
the content security policy of :mod:`.serve`.
"""

from __future__ import annotations

import json
import os
from collections.abc import Mapping
from pathlib import Path

from skyvln_eval.fileio import atomic_write_json
from skyvln_eval.paths import cache_root

#: The folder given to Rerun processes as XDG_CONFIG_HOME.
CONFIG_DIR_NAME = "rerun-config"
#: What users who start Rerun themselves can run (it changes their own config).
USER_OPT_OUT = "rerun analytics disable"


def rerun_config_home() -> Path:
    return cache_root() / CONFIG_DIR_NAME


def _analytics_config(home: Path) -> dict[str, object]:
    # Rerun requires every one of these keys; the id is a constant, not a per-user one.
    return {
        "analytics_enabled": False,
        "analytics_id": "skyvln-eval-analytics-disabled",
        "metadata": {},
        "config_file_path": str(home / "rerun" / "analytics.json"),
        "data_dir_path": str(home / "rerun" / "analytics-data"),
    }


def ensure_analytics_off(home: Path | None = None) -> Path:
    """Write (if needed) the analytics config with analytics off; return its XDG_CONFIG_HOME."""
    home = home or rerun_config_home()
    path = home / "rerun" / "analytics.json"
    wanted = _analytics_config(home)
    try:
        current = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        current = None
    if current != wanted:
        atomic_write_json(path, wanted)
    return home


def rerun_environment(base: Mapping[str, str] | None = None) -> dict[str, str]:
    """The environment for a Rerun process the toolkit starts: analytics off."""
    env = dict(os.environ if base is None else base)
    env["XDG_CONFIG_HOME"] = str(ensure_analytics_off())
    return env
