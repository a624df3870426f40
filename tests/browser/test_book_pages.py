"""Every page of the built book, loaded in headless Chromium (issue 10, part 6). Run by `make browser-check`.

Each page of `_build/html` (index.html, notebooks/*.html, book/*.html) is served on 127.0.0.1 and loaded
with Playwright driving Debian's Chromium; a page fails, with a message naming it and what went wrong, on:

- a JavaScript error: an uncaught exception (`pageerror`) or a console message of type error;
- a request that failed: any request to a host other than 127.0.0.1 (they are all aborted: the book must work
  offline, e.g. MathJax is served from the book's own `_static/mathjax`), or a local one answered >= 400;
- math left unrendered (MathJax did not turn the page's math into `mjx-container`s);
- an image that did not load (`img.complete && img.naturalWidth == 0`), or a figure whose alt text is empty or
  its file's path (each figure cell gives `mystnb.image.alt`: what the figure shows);
- a broken internal link: an `a[href]` to a local file that is not in the build, or to `page.html#anchor`
  with no element of that id in the page;
- a table left as raw pipes: a paragraph whose text has `| ... |` lines and a `---` rule row;
- a table, code block, output, display equation or image wider than the text column (scrolled sideways or past
  the article's edge) on a desktop window of `VIEWPORT`;
- a path of the machine that built the book (`/tmp/...`, `/root/...`, `/home/...`) in the page's text;
- a reference left unresolved or doubled: a role's source (`` {eq}` ``, `` {numref}` ``, ...), a raw label in
  parentheses (`(eq-...)`, `(fig-...)`), or an equation number in two pairs of brackets (`((1))`: `({eq}`x`)`);
- an animation (matplotlib `to_jshtml`) whose frame does not change within ~1 s of pressing play;
- a figure or animation frame (not an SVG) drawn at fewer than `BOOK_PIXEL_DENSITY` image pixels per displayed
  pixel: blurry on a high-density screen;
- a figure or animation frame shrunk to fit the column below `MIN_FIGURE_SCALE` of its own size: the book draws
  its fonts at 11 pt (10.5 pt ticks) at `slamlib.plotstyle.BOOK_DPI`, so they stay at >= 10 pt on the page only
  if the image is shown at (nearly) its own size, on a desktop window of `VIEWPORT`;
- an output image, animation or video without a numbered caption: every figure is a myst-nb figure
  (`mystnb.figure` cell metadata, a `<figure>` with a `<figcaption>`) that the prose can cite with `{numref}`.

Environment: BOOK_HTML (default `_build/html`), CHROMIUM (default /usr/bin/chromium). The test runs only with
BOOK_BROWSER_CHECK=1 (set by `make browser-check`, which installs Chromium and Playwright first), so `make test`
(before `make book`) skips it; with it, a missing build, Playwright or Chromium is an error.
"""

from __future__ import annotations

import functools
import http.server
import os
import posixpath
import re
import shutil
import threading
from pathlib import Path
from urllib.parse import unquote, urlsplit

import pytest

from slamlib.plotstyle import BOOK_PIXEL_DENSITY

ROOT = Path(__file__).resolve().parents[2]
BUILD = Path(os.environ.get("BOOK_HTML", ROOT / "_build" / "html")).resolve()
CHROMIUM = os.environ.get("CHROMIUM", "/usr/bin/chromium")
REQUIRED = os.environ.get("BOOK_BROWSER_CHECK") == "1"
PAGE_TIMEOUT_MS = 30_000
#: A desktop browser window (CSS px); the book's text column is then about 690 px wide.
VIEWPORT = {"width": 1280, "height": 900}
#: Smallest displayed / natural width of a figure: 11 pt text then shows at >= 10 pt.
MIN_FIGURE_SCALE = 10 / 11


def _pages() -> list[str]:
    if not (BUILD / "index.html").is_file():
        return []
    found = [
        BUILD / "index.html",
        *sorted(BUILD.glob("notebooks/*.html")),
        *sorted(BUILD.glob("book/*.html")),
    ]
    return [p.relative_to(BUILD).as_posix() for p in found]


PAGES = _pages()


if not REQUIRED:
    pytestmark = pytest.mark.skip(
        reason="the browser check runs under `make browser-check` (BOOK_BROWSER_CHECK=1)"
    )


def _missing(why: str):
    if REQUIRED:
        pytest.fail(f"browser check cannot run: {why}", pytrace=False)
    pytest.skip(why)


class _QuietHandler(http.server.SimpleHTTPRequestHandler):
    def log_message(self, format, *args):  # noqa: A002 - the base class's name
        pass


@pytest.fixture(scope="module")
def server():
    """The built book over HTTP on 127.0.0.1 (a free port), in a thread."""
    handler = functools.partial(_QuietHandler, directory=str(BUILD))
    httpd = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
    thread = threading.Thread(target=httpd.serve_forever, daemon=True)
    thread.start()
    yield f"http://127.0.0.1:{httpd.server_address[1]}/"
    httpd.shutdown()
    httpd.server_close()


@pytest.fixture(scope="module")
def browser():
    try:
        from playwright.sync_api import sync_playwright
    except ImportError:
        _missing("playwright is not installed (make browser-check installs it)")
    if not Path(CHROMIUM).exists() and not shutil.which(CHROMIUM):
        _missing(
            f"no Chromium at {CHROMIUM} (make browser-check installs Debian's chromium)"
        )
    with sync_playwright() as pw:
        b = pw.chromium.launch(
            executable_path=CHROMIUM, headless=True, args=["--no-sandbox"]
        )
        yield b
        b.close()


@functools.cache
def _ids(path: Path) -> frozenset[str]:
    """The element ids (and old-style `<a name=...>` targets) in one built HTML file."""
    text = path.read_text(encoding="utf-8", errors="replace")
    return frozenset(
        unquote(m) for m in re.findall(r'\b(?:id|name)\s*=\s*["\']([^"\']+)["\']', text)
    )


def _check_links(base: str, hrefs: list[str]) -> list[str]:
    problems = []
    for href in sorted(set(hrefs)):
        if not href.startswith(base):
            continue  # another host, mailto:, javascript: ... not ours to check
        parts = urlsplit(href)
        rel = unquote(parts.path)[len(urlsplit(base).path) :]
        target = BUILD / rel
        if rel == "" or rel.endswith("/"):
            target = target / "index.html"
        if not target.exists():
            problems.append(
                f"broken internal link {href[len(base) - 1 :]}: {target.relative_to(BUILD)} is not in the build"
            )
            continue
        if (
            parts.fragment
            and target.suffix == ".html"
            and unquote(parts.fragment) not in _ids(target)
        ):
            problems.append(
                f"broken internal link {href[len(base) - 1 :]}: no id {parts.fragment!r} in {rel}"
            )
    return problems


_PIPE_ROW = re.compile(r"^\s*\|.*\|\s*$")
_RULE_ROW = re.compile(r"^\s*\|?\s*:?-{3,}")


def _raw_tables(paragraphs: list[str]) -> list[str]:
    problems = []
    for text in paragraphs:
        lines = text.splitlines()
        if any(_PIPE_ROW.match(line) for line in lines) and any(
            _RULE_ROW.match(line) for line in lines
        ):
            first = next(line for line in lines if _PIPE_ROW.match(line)).strip()
            problems.append(
                f"table left as raw pipes (a <p>, not a <table>): {first[:100]!r}"
            )
    return problems


#: Text a resolved reference never leaves on a page: a role's source, a raw label, a doubled equation number.
_BAD_REFERENCES = (
    (
        re.compile(r"\{(?:eq|numref|ref|doc|cite(?::[pt])?|term|prf:ref)\}`"),
        "a role left as its source",
    ),
    (re.compile(r"\((?:eq|fig|tab|sec)-[A-Za-z0-9_-]+\)"), "a raw label"),
    (re.compile(r"\(\(\d+(?:\.\d+)*\)\)"), "an equation number in two pairs of brackets"),
)


def _bad_references(text: str) -> list[str]:
    """One problem per reference left unresolved or doubled in the page's ``text``, quoting it in context."""
    problems = []
    for pattern, what in _BAD_REFERENCES:
        for m in pattern.finditer(text):
            around = text[max(0, m.start() - 40) : m.end() + 40].replace("\n", " ")
            problems.append(f"{what}: {m.group(0)!r} in ...{around}...")
    return problems


#: A path of the machine that built the book (a temporary or home folder, the checkout): meaningless to a reader.
_BUILD_PATH = re.compile(
    r"(?<![\w.~])/(?:tmp|root|home|work|private|var/folders)/[^\s'\"),;]*"
)


def _build_paths(text: str) -> list[str]:
    """One problem per distinct path of the building machine in the page's ``text``."""
    return [
        f"a path of the machine that built the book: {path!r}"
        for path in sorted({m.group(0) for m in _BUILD_PATH.finditer(text)})
    ]


# Runs in the page after load: makes lazy images load, waits for every image to settle, waits for MathJax.
_SETTLE_JS = """async () => {
  const imgs = Array.from(document.images);
  imgs.forEach(i => { if (i.loading === 'lazy') i.loading = 'eager'; });
  const settle = i => i.complete ? Promise.resolve() : new Promise(r => {
      i.addEventListener('load', r, {once: true}); i.addEventListener('error', r, {once: true});
      setTimeout(r, 10000); });
  await Promise.all(imgs.map(settle));
  if (window.MathJax && MathJax.startup && MathJax.startup.promise) {
    await Promise.race([MathJax.startup.promise, new Promise(r => setTimeout(r, 15000))]);
  }
}"""

# The visible blocks of the article wider than their own box (scrolled sideways, part of them hidden) or reaching
# past the article's right edge: tables, code and output, display math, images.
_OVERFLOW_JS = """() => {
  const art = document.querySelector('article') || document.body;
  const edge = art.getBoundingClientRect().right;
  const blocks = 'table, pre, div.math, mjx-container[display="true"], .cell_output, div.highlight, '
      + '.pst-scrollable-table-container, img';
  return Array.from(art.querySelectorAll(blocks))
      .filter(el => el.getClientRects().length > 0)
      .filter(el => el.scrollWidth > el.clientWidth + 1 || el.getBoundingClientRect().right > edge + 1)
      .map(el => `${el.tagName.toLowerCase()} ${el.scrollWidth} px wide in ${el.clientWidth} px: `
           + (el.innerText || el.getAttribute('src') || '').trim().replace(/\\s+/g, ' ').slice(0, 70));
}"""

_INSPECT_JS = """() => ({
  brokenImages: Array.from(document.images)
      .filter(i => i.complete && i.naturalWidth === 0)
      .map(i => (i.getAttribute('src') || '(no src)').slice(0, 120)),
  hrefs: Array.from(document.querySelectorAll('a[href]')).map(a => a.href),
  paragraphs: Array.from(document.querySelectorAll('p')).map(p => p.textContent).filter(t => t.includes('|')),
  articleText: (document.querySelector('article') || document.body).innerText,
  mathNodes: document.querySelectorAll('.math, span.math, div.math').length,
  mathJaxLoaded: !!(window.MathJax && MathJax.version),
  mathRendered: document.querySelectorAll('mjx-container').length,
  animations: Array.from(document.querySelectorAll('img[id^="_anim_img"]')).map(i => i.id),
  videos: Array.from(document.querySelectorAll('article video'))
      .map(v => !!(v.closest('figure') && v.closest('figure').querySelector('figcaption'))),
  outputImages: Array.from(document.querySelectorAll('.cell_output img'))
      .filter(i => i.naturalWidth > 0 && i.getClientRects().length > 0)   // loaded and not in a folded cell
      .map(i => ({src: i.id || (i.getAttribute('src') || '').slice(0, 80), natural: i.naturalWidth,
                  // the size the page asks for (a retina PNG's 1x size), else the image's own
                  intended: parseFloat(i.style.width) || parseFloat(i.getAttribute('width')) || i.naturalWidth,
                  svg: (i.getAttribute('src') || '').includes('svg'), alt: i.getAttribute('alt') || '',
                  shown: i.getBoundingClientRect().width, animation: i.id.startsWith('_anim_img'),
                  captioned: !!(i.closest('figure') && i.closest('figure').querySelector('figcaption'))})),
})"""

# Presses an animation's play button and reports whether its frame (the img src) changed within ~1 s.
_ANIMATE_JS = """async (imgId) => {
  const img = document.getElementById(imgId);
  const uuid = imgId.replace('_anim_img', '');
  const root = img.closest('.animation') || document;
  const play = root.querySelector(`button[onclick*="anim${uuid}.play_animation"]`)
      || document.querySelector(`button[onclick*="anim${uuid}.play_animation"]`);
  if (!play) return 'no play button found';
  const before = img.src;
  play.click();
  await new Promise(r => setTimeout(r, 1000));
  const after = img.src;
  const pause = document.querySelector(`button[onclick*="anim${uuid}.pause_animation"]`);
  if (pause) pause.click();
  return before === after ? 'the frame did not change within 1 s of pressing play' : null;
}"""


@pytest.mark.parametrize("page_path", PAGES or ["(no built book)"])
def test_book_page(page_path, server, browser):
    if not PAGES:
        _missing(f"no built book at {BUILD} (run `make book` first)")
    problems: list[str] = []
    context = browser.new_context(viewport=VIEWPORT)
    page = context.new_page()
    page.set_default_timeout(PAGE_TIMEOUT_MS)

    def route(
        r,
    ):  # the book must not need the network: every request off this machine is refused
        host = urlsplit(r.request.url).hostname
        if r.request.url.startswith(("data:", "blob:", "about:")) or host == "127.0.0.1":
            r.continue_()
        else:
            r.abort()

    page.route("**/*", route)
    page.on("pageerror", lambda exc: problems.append(f"JavaScript error: {exc}"))
    page.on(
        "console",
        lambda msg: (
            problems.append(f"console error: {msg.text[:300]}")
            if msg.type == "error"
            else None
        ),
    )
    page.on(
        "requestfailed",
        lambda req: problems.append(
            f"request failed: {req.url[:200]} ({req.failure or 'failed'})"
            + (
                ""
                if urlsplit(req.url).hostname == "127.0.0.1"
                else " - an external host: the book must work offline"
            )
        ),
    )
    page.on(
        "response",
        lambda resp: (
            problems.append(f"HTTP {resp.status} for {resp.url[:200]}")
            if resp.status >= 400
            else None
        ),
    )
    try:
        refresh = re.search(
            r'http-equiv="Refresh"\s+content="\d+;\s*url=([^"]+)"',
            (BUILD / page_path).read_text(encoding="utf-8", errors="replace"),
            re.I,
        )
        if refresh:  # index.html: a redirect to the first page, which must exist and load (checked from there)
            target = urlsplit(
                server + posixpath.join(posixpath.dirname(page_path), refresh.group(1))
            )
            with page.expect_navigation(
                url=lambda url: urlsplit(url).path == target.path, wait_until="load"
            ):
                page.goto(server + page_path)
        else:
            page.goto(server + page_path, wait_until="load")
        page.evaluate(_SETTLE_JS)
        info = page.evaluate(_INSPECT_JS)
        problems += [f"image did not load: {src}" for src in info["brokenImages"]]
        problems += _check_links(server, info["hrefs"])
        problems += _raw_tables(info["paragraphs"])
        problems += _bad_references(info["articleText"])
        problems += _build_paths(info["articleText"])
        problems += [
            f"wider than the text column at {VIEWPORT['width']} px (cut off or scrolled sideways): {what}"
            for what in page.evaluate(_OVERFLOW_JS)
        ]
        if info["mathNodes"] and not info["mathRendered"]:
            problems.append(
                f"{info['mathNodes']} math element(s) not rendered (MathJax loaded: {info['mathJaxLoaded']})"
            )
        for im in info["outputImages"]:
            if im["shown"] < MIN_FIGURE_SCALE * im["intended"]:
                problems.append(
                    f"image {im['src']} is {im['intended']:.0f} px wide but shown at {im['shown']:.0f} px: "
                    f"its fonts fall below 10 pt (draw it at most "
                    f"{im['shown'] / MIN_FIGURE_SCALE / 100:.1f} in wide at 100 dpi)"
                )
            if not im["svg"] and im["natural"] < BOOK_PIXEL_DENSITY * im["intended"]:
                problems.append(
                    f"image {im['src']} has {im['natural']} px for {im['intended']:.0f} px shown: draw it at "
                    f"{BOOK_PIXEL_DENSITY}x pixel density (slamlib.plotstyle.book_style in the set-up cell)"
                )
            if not im["animation"] and (
                not im["alt"].strip()
                or re.search(r"\.(png|jpe?g|svg|gif)$|_images/", im["alt"])
            ):
                problems.append(
                    f"image {im['src']} has no alt text of its own ({im['alt']!r}): give its figure cell "
                    "mystnb.image.alt, what the figure shows"
                )
            if not im["captioned"]:
                what = "animation" if im["animation"] else "image"
                problems.append(
                    f"{what} {im['src']} has no numbered caption (give its cell mystnb.figure metadata)"
                )
        problems += [
            f"video {i + 1} has no numbered caption (give its cell mystnb.figure metadata)"
            for i, captioned in enumerate(info["videos"])
            if not captioned
        ]
        for img_id in info["animations"]:
            why = page.evaluate(_ANIMATE_JS, img_id)
            if why:
                problems.append(f"animation {img_id}: {why}")
    finally:
        context.close()
    if problems:
        pytest.fail(
            f"{page_path}: {len(problems)} problem(s):\n  - " + "\n  - ".join(problems),
            pytrace=False,
        )


def test_bad_references_are_found_and_good_ones_pass():
    """The reference check on planted page texts (it runs without a built book)."""
    assert _bad_references("as in (1), with the bias of equation (4) and Fig. 3") == []
    found = _bad_references(
        "that is ((1)); the fit (eq-tilt-bias) and {numref}`fig-x` and ((4.2))"
    )
    assert [p.split(":")[0] for p in found] == [
        "a role left as its source",
        "a raw label",
        "an equation number in two pairs of brackets",
        "an equation number in two pairs of brackets",
    ]


def test_build_paths_are_found_and_a_readers_paths_pass():
    """The build-path check on planted page texts (it runs without a built book)."""
    ok = "cached in ~/.cache/slamlib; open _build/html/index.html; Chromium at /usr/bin/chromium"
    assert _build_paths(ok) == []
    found = _build_paths(
        "--data /tmp/swfull/data --out /tmp/swfull/all; from '/root/x/steps.py'> and /tmp/swfull/all"
    )
    assert found == [
        "a path of the machine that built the book: '/root/x/steps.py'",
        "a path of the machine that built the book: '/tmp/swfull/all'",
        "a path of the machine that built the book: '/tmp/swfull/data'",
    ]


def test_overflow_is_found_on_a_planted_page(browser):
    """The overflow check on a planted page: a wide table and a long unwrapped line are found, a narrow table and
    a wrapped long line pass."""
    context = browser.new_context(viewport=VIEWPORT)
    page = context.new_page()
    try:
        wide = "".join(
            f"<td>column_{k}_with_a_long_unbreakable_name</td>" for k in range(8)
        )
        page.set_content(
            "<article style='width: 600px'>"
            f"<table id='wide'><tr>{wide}</tr></table>"
            "<table><tr><td>a</td><td>b</td></tr></table>"
            "<pre style='overflow-x: auto'>" + "x" * 300 + "</pre>"
            "<pre style='white-space: pre-wrap; overflow-wrap: anywhere'>"
            + "y"
            * 300
            + "</pre>"
            "</article>"
        )
        found = page.evaluate(_OVERFLOW_JS)
    finally:
        context.close()
    assert len(found) == 2, found
    assert found[0].startswith("table ") and "column_0" in found[0]
    assert found[1].startswith("pre ") and "xxx" in found[1]
