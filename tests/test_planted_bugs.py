"""The four planted bugs stay caught: ``tests/mutation/planted.py`` plants each in a copy of the package and
requires its named unit tests to pass unplanted and fail planted."""

import subprocess
import sys
from pathlib import Path

PLANTED = Path(__file__).parent / "mutation" / "planted.py"


def test_each_planted_bug_fails_its_unit_test():
    r = subprocess.run(
        [sys.executable, str(PLANTED)], capture_output=True, text=True, timeout=600
    )
    assert r.returncode == 0, r.stdout + r.stderr
    rows = [
        line
        for line in r.stdout.splitlines()
        if line.startswith("| ") and "`tests/" in line
    ]
    assert len(rows) == 5 and all(line.endswith("| fails (caught) |") for line in rows), (
        r.stdout
    )
