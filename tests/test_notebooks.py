"""Every chapter runs to its end: each notebook is executed top to bottom, its closing ``assert`` cells included,
and fails on the first cell that raises, naming the notebook, the cell and the traceback.

The executed notebook is stored in the book's execution cache (jupyter-cache, at ``_config.yml``'s
``execute.cache``), the one ``jupyter-book build`` reads with ``execute_notebooks: cache``: myst-nb matches a
notebook to its stored run by a hash of its code cells and kernel, so the book renders these outputs and CI executes
each notebook once, here. ``make book`` drops the cache when any of slamlib's files is newer than it, so the book
never shows outputs of older code. Every run here executes afresh (a stored run is replaced, never trusted).
"""

from pathlib import Path

import nbformat
import pytest
import yaml
from jupyter_cache import get_cache
from jupyter_cache.base import CacheBundleIn
from jupyter_cache.executors.utils import single_nb_execution

ROOT = Path(__file__).resolve().parents[1]
NOTEBOOKS = sorted((ROOT / "notebooks").glob("*.ipynb"))
EXECUTE = yaml.safe_load((ROOT / "_config.yml").read_text(encoding="utf-8"))["execute"]


def test_the_book_reads_the_cache_these_runs_fill():
    assert EXECUTE["execute_notebooks"] == "cache"
    assert EXECUTE["allow_errors"] is False
    assert EXECUTE["cache"]


@pytest.mark.parametrize("path", NOTEBOOKS, ids=lambda p: p.stem)
def test_notebook_runs_to_its_checks(path, book_environment):
    notebook = nbformat.read(
        path, as_version=4
    )  # as myst-nb reads it, so the hashes match
    cache = get_cache(str(ROOT / EXECUTE["cache"]))
    staged = cache.add_nb_to_project(str(path))
    # The same call and arguments as myst-nb's own cache mode (myst_nb.core.execute.cache), in the notebook's folder.
    result = single_nb_execution(
        notebook,
        cwd=str(path.parent),
        allow_errors=False,
        timeout=EXECUTE["timeout"],
        meta_override=True,
    )
    if result.err is not None:
        pytest.fail(
            f"{path.relative_to(ROOT)} failed:\n{result.exc_string}", pytrace=False
        )
    cache.cache_notebook_bundle(
        CacheBundleIn(notebook, staged.uri, data={"execution_seconds": result.time}),
        check_validity=False,
        overwrite=True,
    )
