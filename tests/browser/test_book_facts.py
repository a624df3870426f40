"""One value per fact across the built book's pages (issue 32, "one number per fact"). Run by `make browser-check`.

Every page's glued values are in the build's ``jupyter_execute/**/NAME.glue.json`` (myst-nb writes one per
executed notebook: glue name -> its ``text/plain``). The check fails on:

- one glue name with two different values on two pages (the same key, two numbers);
- a fact of :data:`slamlib.results.FACTS` glued with a value other than the committed one;
- a fact's committed value glued under another name: a page that read the number on its own instead of
  stating the fact (:func:`slamlib.results.glue_facts`), which the first two checks could not see.

The first test runs on planted pages in any test run; the second on the built book, with BOOK_BROWSER_CHECK=1
(BOOK_HTML as for ``test_book_pages.py``; the glue files are in the folder beside it).
"""

from __future__ import annotations

import ast
import json
import math
import os
from pathlib import Path

import pytest

from slamlib.results import FACTS, fact

ROOT = Path(__file__).resolve().parents[2]
BUILD = Path(os.environ.get("BOOK_HTML", ROOT / "_build" / "html")).resolve()
REQUIRED = os.environ.get("BOOK_BROWSER_CHECK") == "1"
#: Relative tolerance of "the same value": glue stores Python's repr, exact for floats.
SAME = 1e-12


def _value(text: str):
    """A glued ``text/plain`` as a Python value (number or string) where it is a literal, else the text."""
    try:
        return ast.literal_eval(text)
    except (ValueError, SyntaxError):
        return text


def _same(a, b) -> bool:
    if isinstance(a, (int, float)) and isinstance(b, (int, float)):
        return math.isclose(a, b, rel_tol=SAME, abs_tol=0.0)
    return a == b


def glued_pages(folder: Path) -> dict[str, dict[str, object]]:
    """Every page's glued values, from the ``*.glue.json`` files under ``folder``: page -> name -> value."""
    pages = {}
    for path in sorted(folder.rglob("*.glue.json")):
        data = json.loads(path.read_text())
        page = path.relative_to(folder).as_posix().removesuffix(".glue.json")
        pages[page] = {
            name: _value(out["data"].get("text/plain", "")) for name, out in data.items()
        }
    return pages


def conflicts(pages: dict[str, dict[str, object]], facts: dict[str, float]) -> list[str]:
    """What breaks "one value per fact" in ``pages`` (page -> glue name -> value), given the committed
    ``facts`` (key -> value): one message per problem, naming the pages, the key and the values."""
    problems = []
    by_name: dict[str, dict[str, object]] = {}
    for page, values in pages.items():
        for name, value in values.items():
            by_name.setdefault(name, {})[page] = value
    for name, where in sorted(by_name.items()):
        first_page, first = next(iter(where.items()))
        for page, value in where.items():
            if not _same(value, first):
                problems.append(
                    f"{name!r}: {first!r} on {first_page} but {value!r} on {page}"
                )
        if name in facts:
            for page, value in where.items():
                if not _same(value, facts[name]):
                    problems.append(
                        f"{name!r} on {page} is {value!r}; the committed fact is {facts[name]!r}"
                    )
    for key, committed in facts.items():
        if float(committed).is_integer():
            continue  # a round number can be another quantity's value by chance
        for name, where in by_name.items():
            if name == key:
                continue
            for page, value in where.items():
                if isinstance(value, float) and _same(value, committed):
                    problems.append(
                        f"{page} glues fact {key!r}'s value {committed!r} as {name!r}: state it with "
                        f"slamlib.results.glue_facts({key!r})"
                    )
    return problems


def test_conflicts_are_found_on_planted_pages():
    facts = {"default-fps": 24.33, "default-ate-m": 0.0744}
    clean = {
        "notebooks/a": {"default-fps": 24.33, "other": 1.5, "n": 300},
        "notebooks/b": {"default-fps": 24.33, "default-ate-m": 0.0744, "other": 1.5},
    }
    assert conflicts(clean, facts) == []
    two_values = {**clean, "notebooks/b": {"other": 1.25}}
    assert conflicts(two_values, facts) == [
        "'other': 1.5 on notebooks/a but 1.25 on notebooks/b"
    ]
    stale = {**clean, "notebooks/b": {"default-ate-m": 0.0591}}
    assert conflicts(stale, facts) == [
        "'default-ate-m' on notebooks/b is 0.0591; the committed fact is 0.0744"
    ]
    renamed = {**clean, "notebooks/b": {"fps_voxel_default": 24.33}}
    (problem,) = conflicts(renamed, facts)
    assert "as 'fps_voxel_default'" in problem and "glue_facts('default-fps')" in problem


def test_glue_files_are_read_per_page(tmp_path):
    folder = tmp_path / "jupyter_execute" / "notebooks"
    folder.mkdir(parents=True)
    out = lambda text: {"output_type": "display_data", "data": {"text/plain": text}}  # noqa: E731
    (folder / "04_slam_3d.glue.json").write_text(
        json.dumps(
            {"default-fps": out("24.33"), "default-fps-machine": out("'2-core X'")}
        )
    )
    assert glued_pages(tmp_path / "jupyter_execute") == {
        "notebooks/04_slam_3d": {"default-fps": 24.33, "default-fps-machine": "2-core X"}
    }


@pytest.mark.skipif(
    not REQUIRED, reason="runs on the built book under `make browser-check`"
)
def test_no_two_pages_state_different_values_for_one_fact():
    folder = BUILD.parent / "jupyter_execute"
    if not folder.is_dir():
        pytest.fail(
            f"no executed notebooks at {folder}: run `make book` first", pytrace=False
        )
    pages = glued_pages(folder)
    assert len(pages) >= 5, (
        f"only {sorted(pages)} glue values: is {folder} a whole build?"
    )
    facts = {key: fact(key).value for key in FACTS}
    stated = {name for values in pages.values() for name in values}
    assert stated & set(FACTS), "no page states a fact of slamlib.results.FACTS"
    problems = conflicts(pages, facts)
    assert not problems, "\n".join(problems)
