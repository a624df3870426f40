"""The layering CONTRIBUTING.md states: what may import what inside slamlib (no upward imports, no benchmarks)."""

import ast
from pathlib import Path

import slamlib

ROOT = Path(slamlib.__file__).parent

#: Layer of each top-level part of slamlib: a module may import only its own layer or lower ones.
LAYERS = {
    "cli": 5,
    "commands": 5,
    "experiments": 4,
    "slam3d": 3,
    "synth": 3,
    "noise_quality": 3,
    "kernels": 2,
    "kitti": 2,
    "sim1d": 2,
    "sim2d": 2,
    "metrics": 2,
    "odometry": 2,
    "peers": 2,
    "maps": 1,
    "noise": 1,
    "geometry": 1,
    "resampling": 1,
    "contract": 1,
    "errors": 1,
    "paths": 1,
    "data": 1,
    "plotstyle": 1,
    "machine": 1,
    "__init__": 6,
    "__main__": 6,
}
#: Pairs inside one layer that must not know each other (CONTRIBUTING.md: kernels and maps know no pipeline,
#: kitti and synth know no filter).
FORBIDDEN = {
    ("kernels", "slam3d"),
    ("maps", "slam3d"),
    ("maps", "kernels"),
    ("kitti", "sim1d"),
    ("kitti", "slam3d"),
    ("synth", "slam3d"),
    ("synth", "sim1d"),
    ("synth", "sim2d"),
    ("sim2d", "slam3d"),
    ("sim2d", "sim1d"),
    ("sim1d", "sim2d"),
}


def imports_of(path: Path) -> set[str]:
    """Top-level parts of slamlib (and 'benchmarks') that the file imports, at any depth of the code."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        names = []
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names = [node.module] + [f"{node.module}.{a.name}" for a in node.names]
        for name in names:
            parts = name.split(".")
            if parts[0] == "benchmarks":
                found.add("benchmarks")
            elif parts[0] == "slamlib" and len(parts) > 1:
                found.add(parts[1])
    return found


def part_of(path: Path) -> str:
    rel = path.relative_to(ROOT)
    return rel.parts[0] if len(rel.parts) > 1 else rel.stem


def test_no_module_imports_upwards_or_the_benchmarks():
    problems = []
    for path in sorted(ROOT.rglob("*.py")):
        me = part_of(path)
        for other in imports_of(path) - {me}:
            if other == "benchmarks":
                if me != "commands":
                    problems.append(f"{path.relative_to(ROOT)} imports benchmarks")
                continue
            if other not in LAYERS:
                continue  # e.g. slamlib.__version__
            if LAYERS[other] > LAYERS[me] or (me, other) in FORBIDDEN:
                problems.append(f"{path.relative_to(ROOT)} ({me}) imports {other}")
    assert problems == []


def test_the_check_sees_an_upward_import(tmp_path):
    bad = tmp_path / "bad.py"
    bad.write_text(
        "def f():\n    from slamlib.slam3d import steps\n    import benchmarks.maps\n"
    )
    assert imports_of(bad) == {"slam3d", "benchmarks"}
