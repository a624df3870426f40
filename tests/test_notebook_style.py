"""The book's notebooks follow the chapter conventions of CONTRIBUTING.md ("Writing a chapter") that a build does
not check by itself: code wrapped to 90 columns, figures numbered and named, each cited from the prose."""

import json
import re
from pathlib import Path

import pytest

NOTEBOOKS = sorted((Path(__file__).resolve().parents[1] / "notebooks").glob("*.ipynb"))
MAX_CODE_COLUMNS = 90


def _cells(path):
    return json.loads(path.read_text(encoding="utf-8"))["cells"]


@pytest.mark.parametrize("path", NOTEBOOKS, ids=lambda p: p.stem)
def test_code_is_wrapped(path):
    long = [
        f"cell {i}: {line.strip()[:60]}... ({len(line)} columns)"
        for i, c in enumerate(_cells(path))
        if c["cell_type"] == "code"
        for line in "".join(c["source"]).splitlines()
        if len(line) > MAX_CODE_COLUMNS
    ]
    assert not long, f"{path.name}: lines over {MAX_CODE_COLUMNS} columns:\n" + "\n".join(
        long
    )


@pytest.mark.parametrize("path", NOTEBOOKS, ids=lambda p: p.stem)
def test_figures_are_named_captioned_and_cited(path):
    cells = _cells(path)
    figures = [
        c["metadata"]["mystnb"]["figure"]
        for c in cells
        if c["cell_type"] == "code"
        and "figure" in c.get("metadata", {}).get("mystnb", {})
    ]
    prose = "".join("".join(c["source"]) for c in cells if c["cell_type"] == "markdown")
    cited = set(re.findall(r"\{numref\}`([^`]+)`", prose))
    for fig in figures:
        assert re.fullmatch(r"fig-[a-z0-9]+-[a-z0-9-]+", fig.get("name", "")), fig
        assert len(fig.get("caption", "")) > 20, fig
        assert fig["name"] in cited, (
            f"{path.name}: figure {fig['name']} is never cited with {{numref}}"
        )
    names = [f["name"] for f in figures]
    assert len(names) == len(set(names)), names
