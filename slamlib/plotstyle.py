"""The book's figure style: one call in each chapter's set-up cell (``from slamlib.plotstyle import book_style``),
animations as self-contained HTML (:func:`animation_html`), legends off the data (:func:`legend_below`) and
results as tables rather than printed text (:func:`markdown_table`).

The book's text column is about 690 px wide. Figures are at most :data:`MAX_FIGURE_WIDTH_IN` inches wide at
``figure.dpi = 100``, so they are shown at (nearly) their own size, and the fonts below stay at 10 pt or more on
the page. In a notebook they are drawn at :data:`BOOK_PIXEL_DENSITY` times that many pixels (IPython's "retina"
PNGs, whose output metadata keeps the displayed size), so that they stay sharp on high-density screens.

Matplotlib warns when placing a legend with ``loc="best"`` takes over a second; that depends only on the
machine's load (a busy CI runner), so the warning is silenced here: otherwise it lands in a cell's stderr and
fails the ``-W`` book build at random.
"""

from __future__ import annotations

import re
import warnings

__all__ = [
    "BOOK_DPI",
    "BOOK_INLINE_FORMAT",
    "BOOK_PIXEL_DENSITY",
    "BOOK_RCPARAMS",
    "MAX_FIGURE_WIDTH_IN",
    "animation_html",
    "book_style",
    "data_under_legend",
    "legend_below",
    "markdown_table",
]

#: Widest figure (inches at 100 dpi) that the book's ~690 px column shows without shrinking the fonts below 10 pt.
MAX_FIGURE_WIDTH_IN = 7.0

#: Pixels per inch of the book's figures and animation frames: 1 pt of font is BOOK_DPI / 72 px on the page.
BOOK_DPI = 100

#: Image pixels per displayed (CSS) pixel of the book's figures: IPython's ``retina`` format
#: (:data:`BOOK_INLINE_FORMAT`) draws each PNG at twice ``figure.dpi`` and records the 1x size in the output's
#: metadata, which the page's ``<img>`` keeps.
BOOK_PIXEL_DENSITY = 2

#: The inline figure format of :func:`book_style`, the one that draws at :data:`BOOK_PIXEL_DENSITY`.
BOOK_INLINE_FORMAT = "retina"

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
    """Apply :data:`BOOK_RCPARAMS`, draw inline figures at :data:`BOOK_PIXEL_DENSITY` (in IPython), and
    silence matplotlib's load-dependent legend-placement warning."""
    import matplotlib.pyplot as plt

    plt.rcParams.update(BOOK_RCPARAMS)
    _inline_format(BOOK_INLINE_FORMAT)
    warnings.filterwarnings(
        "ignore",
        message='Creating legend with loc="best" can be slow',
        category=UserWarning,
    )


def _inline_format(fmt: str) -> None:
    """Inline figures in format ``fmt`` in an IPython kernel; nothing elsewhere (a script, a test)."""
    try:
        from IPython import get_ipython
    except ImportError:  # pragma: no cover - the book's dependency, not slamlib's
        return
    if get_ipython() is None:
        return
    from matplotlib_inline.backend_inline import set_matplotlib_formats

    set_matplotlib_formats(fmt)


#: Points between an axes' x label (or tick labels) and a legend that :func:`legend_below` puts under them.
LEGEND_GAP_PT = 4.0


def legend_below(ax, ncols: int | None = None, **kwargs):
    """Draw ``ax``'s legend under the axes, below its tick labels and x label: off the data, wherever it lies.

    The legend hangs from the axes' bottom edge by the height of what is drawn under it, in points, so it stays
    clear when ``tight_layout`` or ``constrained`` layout resizes the axes afterwards (both make room for it).
    ``ncols`` defaults to all entries on one row, up to 3; ``kwargs`` go to :meth:`~matplotlib.axes.Axes.legend`.
    """
    from matplotlib.transforms import offset_copy

    fig = ax.figure
    if ax.get_legend() is not None:
        ax.get_legend().remove()  # replaced, and not counted in what is under the axes
    fig.canvas.draw()  # the tick labels' and x label's extents exist only once drawn
    below = ax.get_tightbbox(fig.canvas.get_renderer())
    drop_pt = (ax.bbox.y0 - below.y0) * 72.0 / fig.dpi + LEGEND_GAP_PT
    _, labels = ax.get_legend_handles_labels()
    hang = offset_copy(ax.transAxes, fig=fig, y=-drop_pt, units="points")
    options = {"frameon": False, "ncols": ncols or min(len(labels), 3)} | kwargs
    return ax.legend(
        loc="upper center", bbox_to_anchor=(0.5, 0.0), bbox_transform=hang, **options
    )


def data_under_legend(ax) -> int:
    """How many of ``ax``'s data vertices (line points, scatter offsets, bar and patch corners) the legend's box
    covers on the drawn figure: 0 means the legend hides no data. 0 when ``ax`` has no legend."""
    import numpy as np
    from matplotlib.collections import Collection
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch
    from matplotlib.spines import Spine

    legend = ax.get_legend()
    if legend is None:
        return 0
    fig = ax.figure
    fig.canvas.draw()
    box = legend.get_window_extent(fig.canvas.get_renderer())
    points = []
    for artist in ax.get_children():
        if artist is legend or isinstance(artist, Spine) or not artist.get_visible():
            continue
        if isinstance(artist, Line2D):
            xy = np.asarray(artist.get_xydata(), dtype=float)
            points.append(artist.get_transform().transform(xy))
        elif isinstance(artist, Collection) and len(artist.get_offsets()):
            points.append(artist.get_offset_transform().transform(artist.get_offsets()))
        elif isinstance(artist, Patch) and artist is not ax.patch:
            corners = artist.get_window_extent().get_points()
            points.append(
                np.array([corners[0], corners[1], [corners[0, 0], corners[1, 1]]])
            )
    if not points:
        return 0
    xy = np.concatenate(points)
    xy = xy[np.isfinite(xy).all(axis=1)]
    inside = (
        (xy[:, 0] > box.x0)
        & (xy[:, 0] < box.x1)
        & (xy[:, 1] > box.y0)
        & (xy[:, 1] < box.y1)
    )
    return int(inside.sum())


def markdown_table(header, rows):
    """A table for a notebook's output: ``header`` the column names, ``rows`` lists of cells (formatted
    strings), as an ``IPython.display.Markdown`` that the book renders as a table (not preformatted text)."""
    from IPython.display import Markdown

    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(str(cell) for cell in row) + " |" for row in rows]
    return Markdown("\n".join(lines))


#: The stylesheet link matplotlib's ``to_jshtml`` adds for its player icons (Font Awesome 4.4 from a CDN). The
#: book's theme already ships Font Awesome 6, which draws the same icons, and a CDN request fails offline.
_JSHTML_CDN_CSS = re.compile(
    r'<link rel="stylesheet"\s+href="https://[^"]*font-awesome[^"]*"\s*/?>\s*'
)


#: The frame of matplotlib's ``to_jshtml`` player, before its attributes.
_JSHTML_FRAME = '<img id="_anim_img'


def animation_html(anim, **kwargs) -> str:
    """``anim.to_jshtml(**kwargs)`` (every frame embedded, plays without a kernel) without the CDN stylesheet link,
    then closes the animation's figure so that the notebook shows only the player, not a static last frame.

    The frames are drawn at :data:`BOOK_PIXEL_DENSITY` times :data:`BOOK_DPI` and shown at the figure's size at
    :data:`BOOK_DPI` (the frame's ``width``), as the book's figures are: sharp on high-density screens."""
    import matplotlib as mpl
    import matplotlib.pyplot as plt

    fig = anim._fig
    with mpl.rc_context({"savefig.dpi": BOOK_DPI * BOOK_PIXEL_DENSITY}):
        html = _JSHTML_CDN_CSS.sub("", anim.to_jshtml(**kwargs))
    plt.close(fig)
    width = round(fig.get_figwidth() * BOOK_DPI)
    shown = _JSHTML_FRAME.replace("<img ", f'<img style="width: {width}px" ')
    return html.replace(_JSHTML_FRAME, shown, 1)
