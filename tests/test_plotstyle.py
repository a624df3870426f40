"""The book's figure helpers: animations that play offline, the style applied."""

import warnings

import matplotlib
import matplotlib.pyplot as plt
from matplotlib.animation import FuncAnimation

from slamlib.plotstyle import BOOK_RCPARAMS, animation_html, book_style


def test_animation_html_has_every_frame_and_no_off_machine_request():
    fig, ax = plt.subplots()
    (line,) = ax.plot([0, 1], [0, 1])
    anim = FuncAnimation(fig, lambda k: line.set_ydata([0, k]), frames=4)
    assert "font-awesome" in anim.to_jshtml()  # what matplotlib emits: a CDN stylesheet
    html = animation_html(anim, default_mode="once")
    assert "https://" not in html and "http://" not in html
    assert html.count("data:image/png;base64") == 4
    assert not plt.fignum_exists(fig.number)  # closed: no static copy of the last frame


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
