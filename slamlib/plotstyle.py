"""The book's figure style: one call in each chapter's set-up cell (``from slamlib.plotstyle import book_style``),
and animations as self-contained HTML (:func:`animation_html`).

The book's text column is about 690 px wide. Figures are at most :data:`MAX_FIGURE_WIDTH_IN` inches wide at
``figure.dpi = 100``, so they are shown at (nearly) their own size, and the fonts below stay at 10 pt or more on
the page. Matplotlib warns when placing a legend with ``loc="best"`` takes over a second; that depends only on the
machine's load (a busy CI runner), so the warning is silenced here: otherwise it lands in a cell's stderr and
fails the ``-W`` book build at random.
"""

from __future__ import annotations

import re
import warnings

__all__ = [
    "BOOK_DPI",
    "BOOK_RCPARAMS",
    "MAX_FIGURE_WIDTH_IN",
    "animation_html",
    "book_style",
]

#: Widest figure (inches at 100 dpi) that the book's ~690 px column shows without shrinking the fonts below 10 pt.
MAX_FIGURE_WIDTH_IN = 7.0

#: Pixels per inch of the book's figures and animation frames: 1 pt of font is BOOK_DPI / 72 px on the page.
BOOK_DPI = 100

#: Matplotlib settings of the book's figures (points; 11 pt text, 10.5 pt ticks and legends).
BOOK_RCPARAMS = {
    "figure.dpi": BOOK_DPI,
    "font.size": 11,
    "axes.titlesize": 11,
    "axes.labelsize": 11,
    "xtick.labelsize": 10.5,
    "ytick.labelsize": 10.5,
    "legend.fontsize": 10.5,
    "figure.titlesize": 11,
}


def book_style() -> None:
    """Apply :data:`BOOK_RCPARAMS` and silence matplotlib's load-dependent legend-placement warning."""
    import matplotlib.pyplot as plt

    plt.rcParams.update(BOOK_RCPARAMS)
    warnings.filterwarnings(
        "ignore",
        message='Creating legend with loc="best" can be slow',
        category=UserWarning,
    )


#: The stylesheet link matplotlib's ``to_jshtml`` adds for its player icons (Font Awesome 4.4 from a CDN). The
#: book's theme already ships Font Awesome 6, which draws the same icons, and a CDN request fails offline.
_JSHTML_CDN_CSS = re.compile(
    r'<link rel="stylesheet"\s+href="https://[^"]*font-awesome[^"]*"\s*/?>\s*'
)


def animation_html(anim, **kwargs) -> str:
    """``anim.to_jshtml(**kwargs)`` (every frame embedded, plays without a kernel) without the CDN stylesheet link,
    then closes the animation's figure so that the notebook shows only the player, not a static last frame."""
    import matplotlib.pyplot as plt

    html = _JSHTML_CDN_CSS.sub("", anim.to_jshtml(**kwargs))
    plt.close(anim._fig)
    return html
