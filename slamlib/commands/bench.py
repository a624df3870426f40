"""``slamlib bench NAME``: run a benchmark and write its JSON result (with the machine described).

The benchmarks are not part of the library: they live in the ``benchmarks/`` package beside ``slamlib/`` in a
source checkout. This command is the only place slamlib imports them; it finds the checkout from slamlib's own
location (:func:`slamlib.paths.benchmarks_dir`), not from the current folder, and writes the result to
:func:`slamlib.paths.bench_results_dir` (the checkout's ``benchmarks/results`` unless ``--out`` or
``$SLAMLIB_BENCH_RESULTS`` says otherwise). Without a checkout it exits with a one-line message.
"""

from __future__ import annotations

import importlib
import importlib.util
import inspect
import json
import sys
from pathlib import Path
from types import ModuleType

from slamlib import paths

NAME = "bench"
HELP = "Run a benchmark (see --list) and write its JSON result under benchmarks/results/ (from a source checkout)."

PACKAGE = "benchmarks"


def add_arguments(parser) -> None:
    parser.add_argument("name", nargs="?", help="benchmark to run; --list shows them")
    parser.add_argument(
        "--list", action="store_true", help="list the benchmarks and exit"
    )
    parser.add_argument(
        "--quick", action="store_true", help="small sizes, for a smoke test"
    )
    parser.add_argument(
        "--static",
        action="store_true",
        help="static analysis instead of timings, for the benchmarks that offer it (cuda: every "
        "kernel compiled for A100/H100 without a GPU; registers, spills, occupancy); "
        "writes NAME-static.json",
    )
    parser.add_argument(
        "--out",
        type=Path,
        default=None,
        help="output JSON path (default NAME.json, NAME-quick.json with --quick, in the checkout's "
        "benchmarks/results/ or $SLAMLIB_BENCH_RESULTS)",
    )


def load_benchmarks() -> ModuleType:
    """Import the ``benchmarks`` package of the source checkout slamlib runs from, whatever the current folder.

    Raises ``SystemExit`` with a one-line message when slamlib is not run from a source checkout (no
    ``benchmarks/__init__.py`` and ``pyproject.toml`` beside the ``slamlib`` package), or when another module
    named ``benchmarks`` is already imported.
    """
    root = paths.benchmarks_dir()
    init = root / "__init__.py"
    if not (init.is_file() and (root.parent / "pyproject.toml").is_file()):
        raise SystemExit(
            "slamlib bench runs from a source checkout of slamlib (git clone the slamlib repository; "
            f"pip install -e .): no benchmarks/ package beside {root.parent / 'slamlib'}"
        )
    loaded = sys.modules.get(PACKAGE)
    if loaded is not None:
        if (
            getattr(loaded, "__file__", None)
            and Path(loaded.__file__).resolve() == init.resolve()
        ):
            return loaded
        raise SystemExit(
            f"slamlib bench: another module named {PACKAGE!r} is already imported "
            f"({getattr(loaded, '__file__', loaded)}), not {init}"
        )
    spec = importlib.util.spec_from_file_location(
        PACKAGE, init, submodule_search_locations=[str(root)]
    )
    module = importlib.util.module_from_spec(spec)
    sys.modules[PACKAGE] = module
    try:
        spec.loader.exec_module(module)
    except BaseException:
        del sys.modules[PACKAGE]
        raise
    return module


def load_benchmark(name: str) -> ModuleType:
    """The module of benchmark ``name`` (``HELP``, ``run(quick)``), loaded by :func:`load_benchmarks`."""
    registry = load_benchmarks().BENCHMARKS
    if name not in registry:
        raise SystemExit(
            f"slamlib bench: unknown benchmark {name!r}; known: {', '.join(registry)}"
        )
    return importlib.import_module(registry[name])


def main(args) -> int:
    registry = load_benchmarks().BENCHMARKS
    if args.list or not args.name:
        for name in registry:
            print(f"{name:16s} {load_benchmark(name).HELP}")
        return 0
    module = load_benchmark(args.name)
    describe = importlib.import_module(f"{PACKAGE}.machine").describe
    static = bool(getattr(args, "static", False))
    if static and "static" not in inspect.signature(module.run).parameters:
        print(f"slamlib bench: {args.name} offers no --static analysis", file=sys.stderr)
        return 2
    result = {"benchmark": args.name, "quick": bool(args.quick), "machine": describe()}
    result.update(
        module.run(quick=args.quick, static=True)
        if static
        else module.run(quick=args.quick)
    )
    suffix = ("-static" if static else "") + ("-quick" if args.quick else "")
    out = args.out or paths.bench_results_dir() / f"{args.name}{suffix}.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=2) + "\n")
    print(json.dumps(result, indent=2))
    print(f"wrote {out}")
    return 0
