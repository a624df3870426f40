"""The book's figure helpers: animations that play offline, the style applied, legends off the data."""

import base64
import warnings

import matplotlib
import matplotlib.pyplot as plt
import numpy as np
from matplotlib.animation import FuncAnimation

from slamlib.plotstyle import (
    BOOK_DPI,
    BOOK_PIXEL_DENSITY,
    BOOK_RCPARAMS,
    animation_html,
    book_style,
    data_under_legend,
    legend_below,
    markdown_table,
)


def test_animation_html_has_every_frame_and_no_off_machine_request():
    fig, ax = plt.subplots()
    (line,) = ax.plot([0, 1], [0, 1])
    anim = FuncAnimation(fig, lambda k: line.set_ydata([0, k]), frames=4)
    assert "font-awesome" in anim.to_jshtml()  # what matplotlib emits: a CDN stylesheet
    html = animation_html(anim, default_mode="once")
    assert "https://" not in html and "http://" not in html
    assert html.count("data:image/png;base64") == 4
    assert not plt.fignum_exists(fig.number)  # closed: no static copy of the last frame
    # frames at the book's pixel density, shown at the figure's size (a new animation: to_jshtml keeps its
    # first result, the plain one above)
    fig, ax = plt.subplots()
    (line,) = ax.plot([0, 1], [0, 1])
    html = animation_html(FuncAnimation(fig, lambda k: line.set_ydata([0, k]), frames=2))
    width = round(fig.get_figwidth() * BOOK_DPI)
    assert f'<img style="width: {width}px" id="_anim_img' in html
    frame = base64.b64decode(html.split("data:image/png;base64,")[1].split('"')[0])
    assert (
        int.from_bytes(frame[16:20], "big") == BOOK_PIXEL_DENSITY * width
    )  # the PNG's width


def test_book_style_sets_the_fonts_and_silences_only_the_legend_timing_warning():
    with matplotlib.rc_context():
        book_style()
        assert all(matplotlib.rcParams[k] == v for k, v in BOOK_RCPARAMS.items())
    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always")
        book_style()  # inserts its filter in front of "always"
        warnings.warn(
            'Creating legend with loc="best" can be slow with large amounts of data.',
            UserWarning,
            stacklevel=1,
        )
        warnings.warn("something else", UserWarning, stacklevel=1)
    assert [str(w.message) for w in seen] == ["something else"]


def test_legend_below_moves_a_legend_off_the_data_and_clear_of_the_x_label():
    fig, ax = plt.subplots(figsize=(5, 3))
    x = np.linspace(0, 1, 400)
    ax.plot(x, np.sin(40 * x), label="fills the axes")
    ax.plot(x, np.cos(40 * x), label="also")
    ax.set_xlabel("t (s)")
    ax.legend(loc="center")
    assert data_under_legend(ax) > 0  # a legend inside covers data
    legend = legend_below(ax)
    fig.tight_layout()
    assert data_under_legend(ax) == 0
    fig.canvas.draw()
    renderer = fig.canvas.get_renderer()
    box = legend.get_window_extent(renderer)
    label = ax.xaxis.label.get_window_extent(renderer)
    assert box.y1 <= label.y0  # under the x label, not on it
    assert (
        ax.get_legend() is legend and len(legend.get_texts()) == 2
    )  # one legend, both entries
    plt.close(fig)


def test_data_under_legend_is_zero_without_a_legend():
    fig, ax = plt.subplots()
    ax.plot([0, 1], [0, 1])
    assert data_under_legend(ax) == 0
    plt.close(fig)


def test_markdown_table_is_a_pipe_table_with_one_row_per_row():
    table = markdown_table(["map", "ATE (m)"], [["voxel", "0.079"], ["bvh", 0.12]])
    assert table.data.splitlines() == [
        "| map | ATE (m) |",
        "|---|---|",
        "| voxel | 0.079 |",
        "| bvh | 0.12 |",
    ]
