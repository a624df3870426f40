"""``slamlib bench``: loads the checkout's benchmarks/ package from any folder, writes to one results folder."""

import ast
import json
import subprocess
import sys

import pytest

import slamlib
from slamlib import paths
from slamlib.cli import main
from slamlib.commands.bench import load_benchmarks

NAMES = (
    "kernels",
    "maps",
    "noise",
    "cuda",
    "slam3d",
    "synth",
    "peers",
    "transform",
    "particles",
    "scaling",
    "lidar_only",
    "startup",
    "stages",
    "loops2d",
    "loops",
    "loops_route",
)


def test_list_shows_every_benchmark_from_any_folder(tmp_path):
    res = subprocess.run(
        [sys.executable, "-m", "slamlib.cli", "bench", "--list"],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert res.returncode == 0, res.stderr
    listed = [line.split()[0] for line in res.stdout.splitlines() if line.strip()]
    assert listed == list(NAMES)
    # with HELP
    assert all(
        len(line.split(maxsplit=1)) == 2
        for line in res.stdout.splitlines()
        if line.strip()
    )


def test_benchmarks_package_is_the_one_beside_slamlib():
    package = load_benchmarks()
    assert package.__file__ == str(paths.SOURCE_ROOT / "benchmarks" / "__init__.py")
    assert paths.SOURCE_ROOT == paths.benchmarks_dir().parent
    assert tuple(package.BENCHMARKS) == NAMES
    assert load_benchmarks() is package


def test_without_a_source_checkout_it_says_so_in_one_line(tmp_path, monkeypatch):
    # an installed slamlib: no benchmarks/ beside it
    monkeypatch.setattr(paths, "SOURCE_ROOT", tmp_path)
    with pytest.raises(SystemExit) as exc:
        main(["bench", "--list"])
    message = str(exc.value.code)
    assert "\n" not in message
    assert message.startswith("slamlib bench runs from a source checkout of slamlib")
    assert "pip install -e ." in message and str(tmp_path / "slamlib") in message


def test_unknown_benchmark_is_refused():
    with pytest.raises(
        SystemExit, match="unknown benchmark 'nope'; known: kernels, maps"
    ):
        main(["bench", "nope"])


def test_results_go_to_one_folder_whatever_the_current_folder(
    tmp_path, monkeypatch, capsys
):
    tiny = tmp_path / "mods" / "tiny_bench.py"
    tiny.parent.mkdir()
    tiny.write_text(
        'HELP = "a tiny benchmark"\n\ndef run(quick):\n    return {"value": 1.5, "quick_seen": quick}\n'
    )
    monkeypatch.syspath_prepend(str(tiny.parent))
    monkeypatch.setitem(load_benchmarks().BENCHMARKS, "tiny", "tiny_bench")
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)

    monkeypatch.delenv("SLAMLIB_BENCH_RESULTS", raising=False)
    assert paths.bench_results_dir() == paths.SOURCE_ROOT / "benchmarks" / "results"
    out = tmp_path / "results"
    monkeypatch.setenv("SLAMLIB_BENCH_RESULTS", str(out))
    assert paths.bench_results_dir() == out

    assert main(["bench", "tiny", "--quick"]) == 0
    d = json.loads((out / "tiny-quick.json").read_text())
    assert (
        d["benchmark"] == "tiny"
        and d["quick"] is True
        and d["value"] == 1.5
        and d["quick_seen"] is True
    )
    assert {"cpu", "cores", "gpu", "python", "numpy", "numba", "utc"} <= set(d["machine"])
    assert paths.load_bench_result("tiny-quick") == d
    assert paths.load_bench_result("tiny") is None
    assert not any(elsewhere.iterdir())
    assert f"wrote {out / 'tiny-quick.json'}" in capsys.readouterr().out


def test_committed_results_are_read_from_the_checkout(monkeypatch):
    monkeypatch.delenv("SLAMLIB_BENCH_RESULTS", raising=False)
    d = paths.load_bench_result("kernels")
    assert d is not None and d["benchmark"] == "kernels" and "machine" in d


def test_the_library_never_imports_benchmarks():
    """Only ``slamlib bench`` loads benchmarks/, by path (importlib), never with an import statement."""
    root = paths.SOURCE_ROOT / "slamlib"
    assert (root / "__init__.py").samefile(slamlib.__file__)
    offenders = []
    for path in sorted(root.rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            names = (
                [a.name for a in node.names]
                if isinstance(node, ast.Import)
                else [node.module or ""]
                if isinstance(node, ast.ImportFrom) and node.level == 0
                else []
            )
            offenders += [
                f"{path}:{node.lineno}" for n in names if n.split(".")[0] == "benchmarks"
            ]
    assert offenders == []


def test_benchmarks_chapter_lists_every_benchmark():
    """notebooks/07_benchmarks.ipynb imports only slamlib, so it names the benchmarks itself: keep them in step."""
    nb = json.loads((paths.SOURCE_ROOT / "notebooks" / "07_benchmarks.ipynb").read_text())
    source = "".join(
        "".join(c["source"]) for c in nb["cells"] if c["cell_type"] == "code"
    )
    lines = source.splitlines()
    start = next(i for i, ln in enumerate(lines) if ln.startswith("BENCHMARKS = "))
    text, listed = "", None
    for ln in lines[start:]:  # the tuple, on one line or several, comments dropped
        text += ln.split("#")[0] + "\n"
        try:
            listed = ast.literal_eval(text.split("=", 1)[1].strip())
            break
        except SyntaxError:
            continue
    assert listed == tuple(load_benchmarks().BENCHMARKS)
    assert "import benchmarks" not in source and "from benchmarks" not in source


def test_the_readme_states_the_committed_start_up():
    """The README's cold and warm start-up of `slamlib run` are the committed `slamlib bench startup` medians (IMU
    mode) and Numba's floor, to the tenth of a second, with the date of that run: one number per fact."""
    import re

    result = paths.load_bench_result("startup")
    readme = (paths.SOURCE_ROOT / "README.md").read_text(encoding="utf-8")
    text = " ".join(readme.split())
    found = re.search(
        r"start-up takes ([\d.]+) s, and later runs, .*? cache, ([\d.]+) s", text
    )
    assert found, "the README's start-up sentence"
    rows = result["rows"]["imu"]
    assert float(found.group(1)) == round(rows["cold"]["startup_s_median"], 1)
    assert float(found.group(2)) == round(rows["warm"]["startup_s_median"], 1)
    assert result["machine"]["utc"][:10] in text
    floor = re.search(r"of which ([\d.]+) s is Numba's own import and first call", text)
    assert floor, "the README's Numba floor"
    assert float(floor.group(1)) == round(
        result["rows"]["numba_floor"]["startup_s_median"], 1
    )


def test_the_start_up_benchmarks_numba_floor_times_a_fresh_warm_call(tmp_path):
    """``bench startup``'s Numba floor: fresh interpreters calling one cached kernel, the compile left out."""
    from benchmarks.startup import _numba_floor

    row = _numba_floor(tmp_path, 2)
    assert row["repeat"] == 2
    assert list((tmp_path / "numba-floor").rglob("*.nbi")), "the kernel was cached"
    assert 0 < row["startup_s_min"] <= row["startup_s_median"] < row["wall_s_median"]
