"""``slamlib bench NAME``: run a benchmark and write its JSON result (with the machine described)."""

from __future__ import annotations

import importlib
import json
from pathlib import Path

NAME = "bench"
HELP = "Run a benchmark (see --list) and write its JSON result under benchmarks/results/."


def add_arguments(parser) -> None:
    parser.add_argument("name", nargs="?", help="benchmark to run; --list shows them")
    parser.add_argument("--list", action="store_true", help="list the benchmarks and exit")
    parser.add_argument("--quick", action="store_true", help="small sizes, for a smoke test")
    parser.add_argument("--out", type=Path, default=None,
                        help="output JSON path (default benchmarks/results/NAME.json, NAME-quick.json with --quick)")


def main(args) -> int:
    from slamlib.bench import BENCHMARKS
    from slamlib.bench.machine import describe

    if args.list or not args.name:
        for name, module_name in BENCHMARKS.items():
            print(f"{name:16s} {importlib.import_module(module_name).HELP}")
        return 0
    if args.name not in BENCHMARKS:
        raise SystemExit(f"slamlib bench: unknown benchmark {args.name!r}; known: {', '.join(BENCHMARKS)}")
    module = importlib.import_module(BENCHMARKS[args.name])
    result = {"benchmark": args.name, "quick": bool(args.quick), "machine": describe()}
    result.update(module.run(quick=args.quick))
    out = args.out or Path("benchmarks/results") / f"{args.name}{'-quick' if args.quick else ''}.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=2) + "\n")
    print(json.dumps(result, indent=2))
    print(f"wrote {out}")
    return 0
