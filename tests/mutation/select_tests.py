"""Narrow the test selection of a ``make mutate`` copy: ``python tests/mutation/select_tests.py DIR tests/a.py ...``.

Rewrites ``pytest_add_cli_args_test_selection`` of ``[tool.mutmut]`` in ``DIR/pyproject.toml`` (the copy, never the
checkout) to the given test files (``make mutate MUTATE_TESTS='tests/test_maps.py tests/test_kernels_cpu.py'``):
mutmut runs the selection once to map tests to functions, and with ``NUMBA_DISABLE_JIT=1`` the whole selection is
slow, so a run over one module group selects only the files that test it. No arguments after DIR: no change.
"""

import re
import sys


def main(root: str, tests: list[str]) -> None:
    if not tests:
        return
    path = f"{root}/pyproject.toml"
    text = open(path, encoding="utf-8").read()
    new = (
        "pytest_add_cli_args_test_selection = ["
        + ", ".join(f'"{t}"' for t in tests)
        + "]\n"
    )
    text, n = re.subn(
        r"^pytest_add_cli_args_test_selection = \[.*?\]\n",
        new,
        text,
        count=1,
        flags=re.S | re.M,
    )
    if n != 1:
        sys.exit(f"select_tests: no pytest_add_cli_args_test_selection in {path}")
    open(path, "w", encoding="utf-8").write(text)
    print(f"select_tests: {' '.join(tests)}")


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2:])
