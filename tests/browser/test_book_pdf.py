"""``make pdf``'s printer (``book/_ext/book_pdf.py``): a small book printed to PDF by Debian's Chromium. Run by
`make browser-check` (BOOK_BROWSER_CHECK=1), which installs Chromium and Playwright; the whole book's PDF executes
every chapter again, too long for CI, so CI prints this one-page book with math and a table instead."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
PRINTER = ROOT / "book" / "_ext" / "book_pdf.py"

pytestmark = pytest.mark.skipif(
    os.environ.get("BOOK_BROWSER_CHECK") != "1",
    reason="runs under `make browser-check` (BOOK_BROWSER_CHECK=1), with Chromium and Playwright",
)


def _notebook_with_a_folded_cell(path):
    """A chapter like the book's: a code cell whose input is folded (``hide-input``), with its output."""
    import nbformat

    cell = nbformat.v4.new_code_cell("print('two')", metadata={"tags": ["hide-input"]})
    cell.outputs = [nbformat.v4.new_output("stream", name="stdout", text="two\n")]
    notebook = nbformat.v4.new_notebook(
        cells=[nbformat.v4.new_markdown_cell("# Two\n\nA second chapter."), cell]
    )
    nbformat.write(notebook, path)


def test_a_book_prints_to_pdf_with_debians_chromium(tmp_path):
    book = tmp_path / "book"
    book.mkdir()
    # the book's extensions that stopped the one-page build at a folded cell: sphinx-exercise registers nodes for
    # `singlehtml`, and myst-nb's folded cells are registered for `html` alone (book_pdf.setup mends it)
    (book / "_config.yml").write_text(
        'title: tiny\nexecute:\n  execute_notebooks: "off"\n'
        "sphinx:\n  extra_extensions: [sphinx_exercise]\n"
        f"  local_extensions:\n    book_pdf: {PRINTER.parent}\n"
    )
    # the root page in a folder, as the book's (book/intro): the one page's links are written for index.html's
    # folder, and the printer fails on any file the page cannot load
    (book / "_toc.yml").write_text(
        "format: jb-book\nroot: pages/intro\nchapters:\n- file: pages/two\n"
    )
    (book / "pages").mkdir()
    (book / "pages" / "intro.md").write_text(
        "# One\n\nMath $x^2$.\n\n| a | b |\n|---|---|\n| 1 | 2 |\n"
    )
    _notebook_with_a_folded_cell(book / "pages" / "two.ipynb")
    done = subprocess.run(
        [sys.executable, str(PRINTER), str(book)],
        capture_output=True,
        text=True,
        timeout=600,
        env={**os.environ, "CHROMIUM": os.environ.get("CHROMIUM", "/usr/bin/chromium")},
    )
    assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-2000:]
    pdf = (book / "_build" / "pdf" / "book.pdf").read_bytes()
    assert pdf.startswith(b"%PDF-") and len(re.findall(rb"/Type\s*/Page\b", pdf)) >= 1
    page = (book / "_build" / "html" / "_print.html").read_text()  # the page printed
    assert '<details class="admonition hide' in page and "two" in page


def test_a_missing_chromium_is_named(tmp_path):
    done = subprocess.run(
        [sys.executable, str(PRINTER), str(tmp_path)],
        capture_output=True,
        text=True,
        env={**os.environ, "CHROMIUM": str(tmp_path / "no-chromium")},
    )
    assert done.returncode == 2 and "no Chromium at" in done.stderr
