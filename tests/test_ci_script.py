"""`.ci/run` passes on what pytest passes and fails on anything else, "no tests" included."""

from __future__ import annotations

import os
import stat
import subprocess
from pathlib import Path

import pytest

from tests.conftest import REPO

#: Stands in for python3: `python3 -m venv DIR` makes a virtual environment whose pip does
#: nothing and whose pytest exits with $FAKE_PYTEST_STATUS, as a broken suite would.
FAKE_PYTHON = """#!/bin/sh
if [ "$1" = "-m" ] && [ "$2" = "venv" ]; then
  mkdir -p "$3/bin"
  printf '#!/bin/sh\\nexit 0\\n' > "$3/bin/pip"
  printf '#!/bin/sh\\nexit %s\\n' "$FAKE_PYTEST_STATUS" > "$3/bin/pytest"
  chmod +x "$3/bin/pip" "$3/bin/pytest"
  exit 0
fi
echo "unexpected: python3 $*" >&2
exit 99
"""


@pytest.mark.parametrize(("pytest_status", "ci_status"), [(0, 0), (1, 1), (5, 5)])
def test_ci_fails_unless_pytest_ran_tests_and_passed(
    tmp_path: Path, pytest_status: int, ci_status: int
) -> None:
    fake = tmp_path / "bin" / "python3"
    fake.parent.mkdir()
    fake.write_text(FAKE_PYTHON)
    fake.chmod(fake.stat().st_mode | stat.S_IXUSR)
    # A chromium on PATH: without one, the script (as root) runs apt-get, which a test must
    # not (the machine's packages; the network; left running when the timeout kills bash).
    browser = tmp_path / "bin" / "chromium"
    browser.write_text("#!/bin/sh\nexit 0\n")
    browser.chmod(browser.stat().st_mode | stat.S_IXUSR)
    env = {
        **os.environ,
        "PATH": f"{fake.parent}{os.pathsep}{os.environ['PATH']}",
        "FAKE_PYTEST_STATUS": str(pytest_status),
    }
    done = subprocess.run(
        ["bash", str(REPO / ".ci" / "run")], env=env, capture_output=True, text=True, timeout=60
    )
    assert done.returncode == ci_status, done.stderr
    if pytest_status == 5:
        assert "pytest collected no tests (exit code 5)" in done.stderr
