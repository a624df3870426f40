"""The book's notebooks follow the chapter conventions of CONTRIBUTING.md ("Writing a chapter") that a build does
not check by itself: code wrapped to 90 columns, figures numbered and named, each cited from the prose, plotting code
folded, and each chapter framed: what it teaches and needs first, a summary, exercises with hidden solutions, and
its checks."""

import json
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
NOTEBOOKS = sorted((ROOT / "notebooks").glob("*.ipynb"))
BOOK_PAGES = sorted((ROOT / "book").glob("*.md"))
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
def test_no_prose_line_starts_as_a_comment(path):
    """A Markdown line that starts with ``%`` is a MyST comment: the build drops it without a warning, so a
    sentence wrapped before "% of ..." or "%. ..." silently loses that line."""
    dropped = [
        f"cell {i}: {line[:60]}"
        for i, c in enumerate(_cells(path))
        if c["cell_type"] == "markdown"
        for line in "".join(c["source"]).splitlines()
        if line.lstrip().startswith("%")
    ]
    assert not dropped, f"{path.name}: prose lines MyST reads as comments:\n" + "\n".join(
        dropped
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
    no_alt = [
        c["metadata"]["mystnb"]["figure"]["name"]
        for c in cells
        if "figure" in c.get("metadata", {}).get("mystnb", {})
        and len(c["metadata"]["mystnb"].get("image", {}).get("alt", "").split()) < 4
    ]
    assert not no_alt, (
        f"{path.name}: figures without alt text (mystnb.image.alt): {no_alt}"
    )


# Plotting and plumbing hidden, code that teaches shown: a code cell that makes a figure and is longer than this
# carries a folding tag, unless it is listed below with the reason it stays shown.
MAX_SHOWN_FIGURE_LINES = 15
FIGURE_CALL = re.compile(r"plt\.(subplots|figure)\(|\bfig, ax")
FOLDING_TAGS = {"hide-input", "hide-cell", "remove-input", "remove-cell"}
SHOWN_FIGURE_CELLS = [  # (notebook, cell id, why its code stays shown)
    (
        "04_slam_3d",
        "17620c7d",
        "step 7 by hand: transform_scan runs inside the figure's loop, once per panel",
    ),
]


def _is_long_shown_figure_cell(cell):
    source = "".join(cell["source"])
    return (
        cell["cell_type"] == "code"
        and FIGURE_CALL.search(source) is not None
        and len(source.splitlines()) > MAX_SHOWN_FIGURE_LINES
        and not FOLDING_TAGS & set(cell.get("metadata", {}).get("tags", []))
    )


@pytest.mark.parametrize("path", NOTEBOOKS, ids=lambda p: p.stem)
def test_plotting_code_is_folded(path):
    """A code cell that makes a figure and runs over MAX_SHOWN_FIGURE_LINES lines is tagged `hide-input` (or
    `hide-cell`, `remove-*`), so that the page shows the figure and the code that teaches, not the plotting; the
    few cells whose code teaches although it draws are listed, with a reason, and every listed cell still needs it."""
    cells = _cells(path)
    listed = {cid for stem, cid, _ in SHOWN_FIGURE_CELLS if stem == path.stem}
    long_shown = {c.get("id") for c in cells if _is_long_shown_figure_cell(c)}
    unfolded = sorted(long_shown - listed)
    assert not unfolded, (
        f"{path.name}: figure cells of more than {MAX_SHOWN_FIGURE_LINES} lines shown in full "
        f"(tag them hide-input, split the teaching part off, or list them): {unfolded}"
    )
    stale = sorted(listed - long_shown)
    assert not stale, f"{path.name}: listed but folded, short or gone: {stale}"


CHECKS_HEADING = "## Checks: this chapter's claims, run as tests"


def _markdown(cell):
    return "".join(cell["source"]) if cell["cell_type"] == "markdown" else ""


def _kind(path) -> str:
    """ "chapter" (``NN_topic``) or "appendix" (``appendix_topic``: a record of results, fewer exercises)."""
    return "chapter" if path.stem[:2].isdigit() else "appendix"


@pytest.mark.parametrize("path", NOTEBOOKS, ids=lambda p: p.stem)
def test_every_chapter_has_a_frame(path):
    """A chapter (or appendix) opens with what it teaches and needs, and closes with a summary, exercises with
    hidden solutions (a chapter at least three) and the checks that assert its claims, under one heading, after
    which only code cells follow."""
    cells = _cells(path)
    prose = [_markdown(c) for c in cells]
    kind = _kind(path)
    assert any(
        f":::{{admonition}} In this {kind}" in text
        and "**You will learn**" in text
        and "**You need first**" in text
        for text in prose[:3]
    ), f"{path.name}: no 'In this {kind}' admonition in the first 3 cells"
    assert any(
        line.strip() == "## Summary" for text in prose for line in text.splitlines()
    ), f"{path.name}: no '## Summary' cell"
    text = "\n".join(prose)
    opened = re.findall(r"^:{3,}\{", text, re.M)
    closed = re.findall(r"^:{3,}\s*$", text, re.M)
    assert len(opened) == len(closed), f"{path.name}: an unclosed ::: directive"
    exercises = re.findall(r"^:::\{exercise\}\n:label: (\S+)$", text, re.M)
    solutions = re.findall(r"^:::\{solution\} (\S+)\n:class: dropdown$", text, re.M)
    wanted = 3 if kind == "chapter" else 1
    assert len(exercises) >= wanted, (
        f"{path.name}: {len(exercises)} exercises, want {wanted}"
    )
    assert len(exercises) == len(set(exercises)) and set(solutions) == set(exercises), (
        path.name,
        exercises,
        solutions,
    )
    elsewhere = "\n".join(
        [p.read_text(encoding="utf-8") for p in NOTEBOOKS if p != path]
        + [p.read_text(encoding="utf-8") for p in BOOK_PAGES]
    )
    reused = [
        e for e in exercises if re.search(rf":label: {re.escape(e)}(?![\w-])", elsewhere)
    ]
    assert not reused, (
        f"{path.name}: exercise labels used elsewhere in the book: {reused}"
    )
    checks = CHECKS_HEADING.replace("chapter", kind)
    heading = [i for i, t in enumerate(prose) if t.splitlines()[:1] == [checks]]
    assert len(heading) == 1, f"{path.name}: want one '{checks}' cell"
    after = cells[heading[0] + 1 :]
    assert after and all(c["cell_type"] == "code" for c in after), (
        f"{path.name}: only the check cells may follow '{checks}'"
    )
