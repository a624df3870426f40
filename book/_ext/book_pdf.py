"""``make pdf``: the whole book as one PDF, printed by Debian's Chromium.

Jupyter Book 1's HTML-to-PDF builder (``jupyter-book build --builder pdfhtml``) builds the book as one HTML
page (Sphinx's ``singlehtml``) and prints it with Playwright. jupyter-book 1.0.4 launches Playwright's own
Chromium build (``jupyter_book.pdf._html_to_pdf``), which Playwright downloads from a host this machine cannot
reach; this wrapper replaces that one function with the same steps on ``$CHROMIUM`` (default
``/usr/bin/chromium``, Debian's package, as the browser check uses), waits for MathJax to finish typesetting,
and runs the builder. Usage: ``python book/_ext/book_pdf.py BOOK_DIR [jupyter-book build options]``; the PDF
is ``BOOK_DIR/_build/pdf/book.pdf``.

It is also a Sphinx extension (``_config.yml``'s ``local_extensions``): :func:`setup` gives the one-page builder
the HTML that extensions register for the ``html`` builder alone.
"""

from __future__ import annotations

import asyncio
import os
import re
import sys
from pathlib import Path

#: The browser that prints the book (Debian's package; `make browser-check` and `make pdf` install it).
CHROMIUM = os.environ.get("CHROMIUM", "/usr/bin/chromium")
#: Page margins of the PDF (A4 or Letter, Chromium's default paper).
MARGINS = {"left": "0.5in", "right": "0.5in", "top": "0.5in", "bottom": "0.5in"}
#: Jupyter Book's own print rule: a code cell or its output is not split across two pages.
KEEP_CELLS_WHOLE_CSS = """
div.cell_input, div.cell_output {
    -webkit-column-break-inside: avoid;
    page-break-inside: avoid;
    break-inside: avoid;
}
"""
#: The stylesheets and images a loaded page links but the browser could not load (a file:// page reports no
#: failed request for a missing file, so the page is asked).
UNLOADED_JS = """() => [
    ...Array.from(document.querySelectorAll('link[rel="stylesheet"]')).filter(l => !l.sheet).map(l => l.href),
    ...Array.from(document.images).filter(i => i.complete && i.naturalWidth === 0).map(i => i.src),
]"""
#: Resolves once MathJax has typeset the page (immediately on a page without math).
MATHJAX_DONE_JS = (
    "() => (window.MathJax && MathJax.startup && MathJax.startup.promise) || null"
)


#: The redirect ``index.html`` holds when the book's root page is in a folder (this book's is ``book/intro``).
REDIRECT = re.compile(
    r'<meta http-equiv="Refresh" content="0; url=([^"]+)"', re.IGNORECASE
)
#: The name the one page is printed under, beside ``index.html``.
PRINTED_PAGE = "_print.html"


def one_page(html_file) -> Path:
    """The page to print for the builder's ``html_file`` (its ``index.html``), where its links resolve.

    With the root page in a folder, ``index.html`` only redirects to ``FOLDER/ROOT.html``, and Sphinx's one-page
    builder writes that page's links to ``_static/`` and ``_images/`` as if it sat beside ``index.html``, where
    they are: from its folder the browser found none (a PDF without styles or figures). The page is copied there,
    as :data:`PRINTED_PAGE`, and that copy printed."""
    html_file = Path(html_file)
    redirect = REDIRECT.search(html_file.read_text(encoding="utf-8"))
    if redirect is None:
        return html_file
    page = html_file.parent / redirect.group(1)
    if page.parent == html_file.parent:
        return page
    printed = html_file.parent / PRINTED_PAGE
    printed.write_text(page.read_text(encoding="utf-8"), encoding="utf-8")
    return printed


async def _html_to_pdf(html_file, pdf_file) -> None:
    """jupyter_book.pdf._html_to_pdf on ``CHROMIUM``: load the page (:func:`one_page`), let MathJax finish,
    print it."""
    from playwright.async_api import async_playwright

    async with async_playwright() as pw:
        browser = await pw.chromium.launch(executable_path=CHROMIUM)
        try:
            page = await browser.new_page()
            await page.goto(
                one_page(html_file).resolve().as_uri(), wait_until="networkidle"
            )
            missing = await page.evaluate(UNLOADED_JS)
            if missing:
                raise RuntimeError(
                    f"make pdf: {len(missing)} files the page links did not load, e.g. {missing[:3]}"
                )
            await page.evaluate(MATHJAX_DONE_JS)
            await page.add_style_tag(content=KEEP_CELLS_WHOLE_CSS)
            await page.pdf(path=str(pdf_file), margin=MARGINS, print_background=True)
        finally:
            await browser.close()


def html_to_pdf(html_file, pdf_file) -> None:
    """Print ``html_file`` to ``pdf_file`` with ``CHROMIUM`` (the function jupyter-book calls)."""
    asyncio.run(_html_to_pdf(html_file, pdf_file))


def _one_page_draws_what_pages_draw(app) -> None:
    """Give the ``singlehtml`` builder every node handler registered for ``html`` that it lacks."""
    handlers = app.registry.translation_handlers
    if "singlehtml" in handlers:
        for node, visit_depart in handlers.get("html", {}).items():
            handlers["singlehtml"].setdefault(node, visit_depart)


def setup(app):
    """Sphinx extension: the ``singlehtml`` builder, which the PDF is printed from, draws every node the ``html``
    builder draws.

    Sphinx looks a node's HTML up under the builder's name and falls back to the ``html`` format's only when no
    extension registered any node for ``singlehtml``. sphinx-exercise does, so nodes registered for ``html``
    alone, such as myst-nb 1.4's folded cells (``HideCodeCellNode``), had none in the one-page build, which
    stopped at the first folded cell ("departing unknown node type: HideCodeCellNode"). Once every extension is
    set up, the ``html`` handlers the ``singlehtml`` builder lacks are added to it."""
    app.connect("builder-inited", _one_page_draws_what_pages_draw)
    return {"parallel_read_safe": True, "parallel_write_safe": True}


def main(argv: list[str]) -> int:
    import jupyter_book.pdf
    from jupyter_book.cli.main import main as jupyter_book_main

    if not Path(CHROMIUM).exists():
        print(f"make pdf: no Chromium at {CHROMIUM} (set CHROMIUM=...)", file=sys.stderr)
        return 2
    # jupyter_book.pdf.html_to_pdf runs the module's _html_to_pdf, looked up when called
    jupyter_book.pdf._html_to_pdf = _html_to_pdf
    try:
        jupyter_book_main.main(
            args=["build", *argv, "--builder", "pdfhtml"], standalone_mode=False
        )
    except (
        RuntimeError
    ) as error:  # jupyter-book's "error in building" box, already printed
        print(error, file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
