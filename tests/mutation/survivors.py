"""Every surviving mutant of a ``make mutate`` run as one line: its name and the line it changed.

Usage: ``python tests/mutation/survivors.py RUN_DIR [RUN_DIR ...] > survivors.md`` where each ``RUN_DIR`` is a
``make mutate-run`` folder (``_build/mutate-pure``, ``_build/mutate-jitted``) holding ``results.txt``. For each
mutant not killed (``survived``, ``no tests``, ``suspicious``) it asks ``mutmut show NAME`` in that folder for the
diff and prints ``- `module` `function` N: `old` -> `new` (status)``, grouped by module, so that a reviewer can
write the one-line reason (or the test) the report asks for next to each.
"""

import re
import subprocess
import sys
from collections import defaultdict
from pathlib import Path

from score import KILLED, module_of

MUTMUT = Path(sys.executable).with_name("mutmut")
MAX_SHOWN = 110  # characters of each changed line shown


def _clip(line: str) -> str:
    line = line.strip()
    return line if len(line) <= MAX_SHOWN else line[: MAX_SHOWN - 3] + "..."


def changed_lines(run_dir: Path, name: str) -> tuple[str, str]:
    """The first removed and added lines of ``mutmut show NAME`` (``("", "")`` if it shows none)."""
    diff = subprocess.run(
        [str(MUTMUT), "show", name], cwd=run_dir, capture_output=True, text=True
    ).stdout
    old = next(
        (
            ln[1:]
            for ln in diff.splitlines()
            if ln.startswith("-") and not ln.startswith("---")
        ),
        "",
    )
    new = next(
        (
            ln[1:]
            for ln in diff.splitlines()
            if ln.startswith("+") and not ln.startswith("+++")
        ),
        "",
    )
    return _clip(old), _clip(new)


def function_and_number(name: str) -> tuple[str, str]:
    """``slamlib.x.xǁCǁm__mutmut_7`` -> ``("C.m", "7")``; ``slamlib.x.x_f__mutmut_7`` -> ``("f", "7")``."""
    tail = re.split(r"\.x[_\u01c1]", name, maxsplit=1)[1]
    func, number = tail.rsplit("__mutmut_", 1)
    return func.strip("\u01c1").replace("\u01c1", "."), number


def main(run_dirs: list[str]) -> None:
    alive: dict[str, list[str]] = defaultdict(list)
    for run in map(Path, run_dirs):
        for line in open(run / "results.txt", encoding="utf-8"):
            if "__mutmut_" not in line or ": " not in line:
                continue
            name, status = line.strip().rsplit(": ", 1)
            if status in KILLED or status in ("skipped", "not checked"):
                continue
            old, new = changed_lines(run, name)
            func, number = function_and_number(name)
            alive[module_of(name)].append(
                f"- `{func}` {number}: `{old}` -> `{new}` ({status})"
            )
    for module in sorted(alive):
        print(f"\n### `{module}` ({len(alive[module])})\n")
        print("\n".join(alive[module]))


if __name__ == "__main__":
    main(sys.argv[1:])
