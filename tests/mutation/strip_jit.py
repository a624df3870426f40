"""Remove Numba decorators from the mutated modules of a ``make mutate`` copy, so that mutmut mutates jitted code.

Usage: ``python tests/mutation/strip_jit.py DIR`` where ``DIR`` is the copy (``_build/mutate``): every file that
``[tool.mutmut] only_mutate`` of ``DIR/pyproject.toml`` names (globs) loses its literal Numba decorators
(``@njit``, ``@njit(...)``, ``@numba.njit(...)``, ``@jit``, ``@vectorize``, ``@guvectorize``, ``@stencil``,
``@cfunc``, ``@cuda.jit(...)``) on functions at any depth. mutmut 3 skips every decorated function; without the
decorator it mutates the body. Run the tests with ``NUMBA_DISABLE_JIT=1``: then ``njit`` is the identity and
``numba.prange`` is ``range``, so the stripped copy computes what the jitted code computes, as plain Python.

Each decorator's lines are blanked (not deleted), so line numbers in tracebacks still match the source. Other
decorators (``@property``, ``@dataclass``, ``@lru_cache``, ...) are kept. Factories that compile with a function
call (``njit(inline="always")(f)``, ``cuda.jit(device=True)(f)``, e.g. ``make_code_functions``) need nothing:
mutmut already mutates them, and under ``NUMBA_DISABLE_JIT=1`` their builds are plain Python too. Prints one
line per file changed; exits 1 if a listed file does not parse after stripping.
"""

from __future__ import annotations

import ast
import glob
import os
import sys

import tomllib

JIT_NAMES = {
    "njit",
    "jit",
    "vectorize",
    "guvectorize",
    "stencil",
    "cfunc",
    "generated_jit",
}
JIT_OWNERS = {"numba", "nb", "cuda"}


def is_jit_decorator(node: ast.expr) -> bool:
    """``njit``, ``njit(...)``, ``numba.njit(...)``, ``cuda.jit(...)`` and the like."""
    if isinstance(node, ast.Call):
        node = node.func
    if isinstance(node, ast.Name):
        return node.id in JIT_NAMES
    if isinstance(node, ast.Attribute) and node.attr in JIT_NAMES:
        owner = node.value
        return (
            isinstance(owner, ast.Name)
            and owner.id in JIT_OWNERS
            or (isinstance(owner, ast.Attribute) and owner.attr in JIT_OWNERS)
        )
    return False


def strip_source(source: str) -> tuple[str, int]:
    """``(source without its Numba decorators, number removed)``; removed lines become empty lines."""
    tree = ast.parse(source)
    lines = source.splitlines(keepends=True)
    removed = 0
    for node in ast.walk(tree):
        if not isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            continue
        for dec in node.decorator_list:
            if not is_jit_decorator(dec):
                continue
            # the "@" sits on the expression's first line
            first, last = (
                dec.lineno - 1,
                dec.end_lineno - 1,
            )
            if not lines[first].lstrip().startswith("@"):
                raise ValueError(
                    f"line {dec.lineno}: decorator does not start its line: {lines[first]!r}"
                )
            for i in range(first, last + 1):
                lines[i] = "\n"
            removed += 1
    out = "".join(lines)
    ast.parse(out)
    return out, removed


def listed_files(root: str) -> list[str]:
    with open(os.path.join(root, "pyproject.toml"), "rb") as f:
        cfg = tomllib.load(f)["tool"]["mutmut"]
    files: set[str] = set()
    for pattern in cfg.get("only_mutate", []):
        files.update(
            p
            for p in glob.glob(os.path.join(root, pattern), recursive=True)
            if p.endswith(".py")
        )
    return sorted(files)


def main(root: str) -> int:
    for path in listed_files(root):
        with open(path, encoding="utf-8") as f:
            source = f.read()
        try:
            out, removed = strip_source(source)
        except (SyntaxError, ValueError) as exc:
            print(f"strip_jit: {path}: {exc}", file=sys.stderr)
            return 1
        if removed:
            with open(path, "w", encoding="utf-8") as f:
                f.write(out)
            print(
                f"strip_jit: {os.path.relpath(path, root)}: {removed} Numba decorator(s) removed"
            )
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1] if len(sys.argv) > 1 else "."))
