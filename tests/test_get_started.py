"""The book's "Get started" page (``book/get_started.md``): every command in its ``bash`` blocks runs, so the page
cannot drift from the code.

``slamlib`` commands run as written, in a shell (so ``~`` expands), in a scratch folder whose ``HOME`` holds
synthetic stand-ins in KITTI's layouts where the page points at real data (``~/kitti``: raw drive 2011_09_26 0005
and odometry sequence 07; the download itself is the one step not run). ``make`` targets are run dry (``make -n``:
the target exists and its recipe expands; CI runs ``make test`` and ``make book`` themselves). ``pip`` and
``conda`` lines are checked against the files they name: the extras exist in ``pyproject.toml``, the lock file and
the environment file are there and parse. A line of any other kind fails the test: the page must not list a
command nobody runs.
"""

from __future__ import annotations

import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PAGE = ROOT / "book" / "get_started.md"
SLAMLIB = str(Path(sys.executable).with_name("slamlib"))


def page_commands() -> list[str]:
    """The command lines of the page's ``bash`` blocks (comments and blank lines left out)."""
    blocks = re.findall(r"```bash\n(.*?)```", PAGE.read_text(encoding="utf-8"), re.S)
    return [
        line.strip()
        for block in blocks
        for line in block.splitlines()
        if line.strip() and not line.strip().startswith("#")
    ]


def command_word(line: str) -> str:
    """The command a line runs: its first word after any ``NAME=value`` environment assignments."""
    words = shlex.split(line)
    return next(w for w in words if not re.fullmatch(r"[A-Za-z_]\w*=\S*", w))


def test_command_word_skips_environment_assignments():
    assert command_word("NUMBA_NUM_THREADS=4 slamlib run &") == "slamlib"
    assert command_word("make book") == "make"


def test_the_page_lists_commands_of_every_kind():
    kinds = {command_word(line) for line in page_commands()}
    assert kinds == {"make", ".", "slamlib", "pip", "conda"}


@pytest.fixture(scope="module")
def home(tmp_path_factory):
    """A scratch ``HOME`` with ``~/kitti`` as the page lays it out: a raw drive and an odometry sequence."""
    home = tmp_path_factory.mktemp("home")
    kitti = home / "kitti"
    small = ["--frames", "0:12", "--columns", "300", "--no-progress"]
    for args in (
        ["--out", kitti, "--drive", "5", "--route", "07"],
        [
            "--out",
            kitti / "dataset",
            "--layout",
            "odometry",
            "--sequence",
            "7",
            "--route",
            "07",
        ],
    ):
        subprocess.run(
            [SLAMLIB, "synth", *map(str, args), *small], check=True, capture_output=True
        )
    return home


def _pyproject_extras() -> set[str]:
    import tomllib

    data = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))
    return set(data["project"]["optional-dependencies"])


def _check_pip(line: str) -> None:
    argv = shlex.split(line)
    assert argv[:2] == ["pip", "install"], line
    assert (ROOT / argv[argv.index("-c") + 1]).is_file(), line
    target = argv[argv.index("-e") + 1]
    m = re.fullmatch(r"\.(?:\[([\w,]+)\])?", target)
    assert m, f"{line}: installs {target!r}, not this checkout"
    extras = set(m.group(1).split(",")) if m.group(1) else set()
    assert extras <= _pyproject_extras(), (
        f"{line}: no such extra {extras - _pyproject_extras()}"
    )


def _check_conda(line: str) -> None:
    import yaml

    argv = shlex.split(line)
    assert argv[:3] == ["conda", "env", "create"], line
    env = yaml.safe_load((ROOT / argv[argv.index("-f") + 1]).read_text(encoding="utf-8"))
    assert env["name"] == "slamlib" and "conda-forge" in env["channels"]


@pytest.mark.parametrize("line", page_commands())
def test_every_command_on_the_page_runs(line, home, tmp_path):
    word = command_word(line)
    if word == "make":
        result = subprocess.run(
            ["make", "-n", *shlex.split(line)[1:]],
            cwd=ROOT,
            capture_output=True,
            text=True,
        )
        assert result.returncode == 0, result.stderr
    elif word == ".":
        # the virtual environment the page activates is the one the tests run in, made by `make setup`
        venv = ROOT / shlex.split(line)[1]
        if Path(sys.prefix) != (ROOT / ".venv").resolve():
            pytest.skip("the tests do not run in the checkout's .venv here")
        assert venv.is_file()
    elif word == "pip":
        _check_pip(line)
    elif word == "conda":
        _check_conda(line)
    elif word == "slamlib":
        from slamlib.paths import cache_dir

        env = {
            **os.environ,
            "HOME": str(home),
            "SLAMLIB_CACHE": str(cache_dir()),
            "PATH": f"{Path(SLAMLIB).parent}{os.pathsep}{os.environ.get('PATH', '')}",
        }
        # a line the page starts in the background runs in the foreground here, so that its exit status counts
        command = line.removesuffix("&").rstrip()
        result = subprocess.run(
            ["bash", "-c", command], cwd=tmp_path, env=env, capture_output=True, text=True
        )
        assert result.returncode == 0, (
            f"{line}\n{result.stdout[-2000:]}\n{result.stderr[-2000:]}"
        )
    else:
        pytest.fail(f"the page lists {line!r}, a kind of command this test does not run")
