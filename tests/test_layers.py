"""The layering CONTRIBUTING.md states: what may import what inside slamlib (no upward imports, no benchmarks)."""

import ast
import importlib
import re
import sys
from pathlib import Path

import pytest

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
    "loops": 2,
    "maps": 1,
    "noise": 1,
    "geometry": 1,
    "resampling": 1,
    "contract": 1,
    "errors": 1,
    "atomic": 1,
    "paths": 1,
    "data": 1,
    "plotstyle": 1,
    "machine": 1,
    "results": 1,
    "__init__": 6,
    "__main__": 6,
}
#: Pairs inside one layer that must not know each other (CONTRIBUTING.md: kernels and maps know no pipeline,
#: kitti and synth know no filter, the filter knows no synthetic data).
FORBIDDEN = {
    ("slam3d", "synth"),
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

#: The modules that moved from slam3d to experiments: slam3d keeps a deprecated shim of each (re-export and
#: warn), the one import of ``experiments`` slam3d may hold; nothing else may import the old paths.
MOVED = ("sweep", "video", "render")
SHIMS = {f"slam3d/{name}.py" for name in MOVED}


def imports_of(path: Path, package: str | None = None) -> set[str]:
    """Top-level parts of slamlib (and 'benchmarks') that the file imports, at any depth of the code. Relative
    imports are resolved against ``package`` (by default the file's own package under slamlib)."""
    if package is None:
        package = ".".join(("slamlib", *path.relative_to(ROOT).parts[:-1]))
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        names = []
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:  # from . import x, from ..experiments import sweep
                up = package.split(".")[: len(package.split(".")) - (node.level - 1)]
                base = ".".join(up + ([node.module] if node.module else []))
            names = [base] + [f"{base}.{a.name}" for a in node.names]
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


def layering_problems() -> list[str]:
    """Every import in slamlib that breaks the layering, one line each (file, its part, the part it imports)."""
    problems = []
    for path in sorted(ROOT.rglob("*.py")):
        me = part_of(path)
        found = imports_of(path) - {me}
        if path.relative_to(ROOT).as_posix() in SHIMS and found == {"experiments"}:
            continue  # a deprecated shim that only re-exports its module's new place
        for other in found:
            if other == "benchmarks":
                if me != "commands":
                    problems.append(f"{path.relative_to(ROOT)} imports benchmarks")
                continue
            if other not in LAYERS:
                continue  # e.g. slamlib.__version__
            if LAYERS[other] > LAYERS[me] or (me, other) in FORBIDDEN:
                problems.append(f"{path.relative_to(ROOT)} ({me}) imports {other}")
    return sorted(problems)


def test_no_module_imports_upwards_or_the_benchmarks():
    assert layering_problems() == []


def test_the_check_sees_an_upward_import(tmp_path):
    bad = tmp_path / "bad.py"
    bad.write_text(
        "def f():\n    from slamlib.slam3d import steps\n    import benchmarks.maps\n"
    )
    assert imports_of(bad, package="slamlib.kernels") == {"slam3d", "benchmarks"}


def test_the_check_sees_slam3d_importing_synth_or_experiments(tmp_path):
    """The filter package never imports the synthetic-data generator or the experiment tooling."""
    bad = tmp_path / "bad.py"
    bad.write_text(
        "from slamlib.synth import write_drive\nimport slamlib.experiments.sweep\n"
    )
    found = imports_of(bad, package="slamlib.slam3d")
    assert found == {"synth", "experiments"}
    assert all(LAYERS[o] > LAYERS["slam3d"] or ("slam3d", o) in FORBIDDEN for o in found)
    relative = tmp_path / "relative.py"
    relative.write_text(
        "from ..experiments import sweep\nfrom .. import synth\nfrom . import steps\n"
    )
    assert imports_of(relative, package="slamlib.slam3d") == {
        "experiments",
        "synth",
        "slam3d",
    }


#: An import of a moved module by its old path: ``from slamlib.slam3d.sweep import``, ``import
#: slamlib.slam3d.video``, ``from slamlib.slam3d import render``.
_NAMES = "|".join(MOVED)
OLD_PATH = re.compile(
    rf"(from|import)\s+slamlib\.slam3d\.({_NAMES})\b"
    rf"|from\s+slamlib\.slam3d\s+import\s+(\([\w\s,]*|[\w ,]*)\b({_NAMES})\b"
)


def test_nothing_in_the_repository_imports_the_old_paths():
    """pyproject.toml turns a DeprecationWarning from slamlib into an error only in the code the tests run; this
    finds every import of an old path in the library, tests, benchmarks and notebooks (the shims and this file,
    whose examples below are imports of old paths, aside)."""
    repo = ROOT.parent
    mine = {Path(__file__).resolve()} | {(ROOT / s).resolve() for s in SHIMS}
    users = [
        str(p.relative_to(repo))
        for d in ("slamlib", "tests", "benchmarks", "notebooks")
        for p in sorted((repo / d).rglob("*"))
        if p.suffix in (".py", ".ipynb")
        and ".ipynb_checkpoints" not in p.parts
        and p.resolve() not in mine
        and OLD_PATH.search(p.read_text())
    ]
    assert users == []
    assert OLD_PATH.search("    from slamlib.slam3d.sweep import read_table")
    assert OLD_PATH.search("import slamlib.slam3d.render as r")
    assert OLD_PATH.search("from slamlib.slam3d import (\n    run_drive,\n    video,\n)")
    assert not OLD_PATH.search("from slamlib.slam3d.preprocess import sweep_times")
    assert not OLD_PATH.search("from slamlib.experiments.sweep import read_table")
    assert not OLD_PATH.search("from slamlib.slam3d import steps\nimport video")


@pytest.mark.parametrize("name", MOVED)
def test_an_old_path_warns_and_gives_the_same_objects(name):
    new = importlib.import_module(f"slamlib.experiments.{name}")
    old_name = f"slamlib.slam3d.{name}"
    sys.modules.pop(old_name, None)
    try:
        with pytest.warns(DeprecationWarning, match=rf"slamlib\.experiments\.{name}\b"):
            old = importlib.import_module(old_name)
        assert old.__all__ == new.__all__
        assert all(getattr(old, n) is getattr(new, n) for n in new.__all__)
    finally:
        sys.modules.pop(old_name, None)
        if hasattr(sys.modules["slamlib.slam3d"], name):
            delattr(sys.modules["slamlib.slam3d"], name)


def test_every_part_of_slamlib_has_a_layer():
    """A new package unknown to LAYERS would be skipped as an import, so every part must be listed."""
    assert {part_of(p) for p in ROOT.rglob("*.py")} - LAYERS.keys() == set()
