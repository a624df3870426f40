"""The book's API reference (book/api.md) documents every public module of slamlib, and only modules that exist.

A public module is every ``slamlib/**/*.py`` except ``__main__.py`` and names starting with ``_``; a package's
``__init__.py`` counts as the package. Each is named by an ``.. automodule::`` line inside an ``{eval-rst}`` block
of book/api.md (autodoc writes reStructuredText, which a MyST ``{automodule}`` fence would read as Markdown).
A package documents only the members it defines itself (its re-exports are documented on their modules).
The zero-warning build of the page itself is `make book` (``jupyter-book build --all -W -n``).
"""

import importlib
import importlib.util
import inspect
import re
from pathlib import Path

import pytest
from sphinx.pycode import ModuleAnalyzer

ROOT = Path(__file__).resolve().parents[1]
API_PAGE = ROOT / "book" / "api.md"
#: The reference's pages: the index and one page a package.
API_PAGES = [API_PAGE, *sorted((ROOT / "book" / "api").glob("*.md"))]
TOC = ROOT / "_toc.yml"

#: Public modules left out of the reference on purpose, with the reason (none: every module, the CUDA ones
#: included, imports without a GPU; their kernels compile only when first called).
EXCLUDED: dict[str, str] = {}


def _public_modules() -> list[str]:
    modules = []
    for path in sorted((ROOT / "slamlib").rglob("*.py")):
        parts = list(path.relative_to(ROOT).with_suffix("").parts)
        if parts[-1] == "__main__":
            continue
        if parts[-1] == "__init__":
            parts = parts[:-1]
        if any(part.startswith("_") for part in parts):
            continue
        modules.append(".".join(parts))
    return modules


def _eval_rst_blocks(text: str) -> list[str]:
    return re.findall(r"^(`{3,})\{eval-rst\}[^\n]*\n(.*?)^\1\s*$", text, re.M | re.S)


def _automodules() -> dict[str, list[str]]:
    """``{module: its option lines}`` for every ``.. automodule::`` of the page's eval-rst blocks."""
    found: dict[str, list[str]] = {}
    text = "\n".join(p.read_text(encoding="utf-8") for p in API_PAGES)
    for _fence, body in _eval_rst_blocks(text):
        for m in re.finditer(
            r"^\.\. automodule:: *(\S+)\n((?:[ \t]+:.*\n?)*)", body, re.M
        ):
            assert m.group(1) not in found, (
                f"{m.group(1)} documented twice in book/api.md"
            )
            found[m.group(1)] = [line.strip() for line in m.group(2).splitlines()]
    return found


PUBLIC = _public_modules()
DOCUMENTED = _automodules()
PACKAGES = [m for m in PUBLIC if (ROOT / m.replace(".", "/") / "__init__.py").is_file()]


def test_the_pages_are_in_the_toc():
    files = re.findall(
        r"^\s*-\s*file:\s*(\S+)\s*$", TOC.read_text(encoding="utf-8"), re.M
    )
    pages = [str(p.relative_to(ROOT).with_suffix("")) for p in API_PAGES]
    assert len(pages) > 10 and not set(pages) - set(files), (
        f"not in _toc.yml: {sorted(set(pages) - set(files))}"
    )


def test_every_public_module_is_documented():
    assert len(PUBLIC) > 50, PUBLIC
    missing = [m for m in PUBLIC if m not in DOCUMENTED and m not in EXCLUDED]
    assert not missing, (
        "public modules missing from book/api.md (add an automodule):\n"
        + "\n".join(missing)
    )


def test_every_documented_module_exists():
    unknown = [m for m in DOCUMENTED if importlib.util.find_spec(m) is None]
    assert not unknown, f"book/api.md names modules that do not exist: {unknown}"
    private = [m for m in DOCUMENTED if m not in PUBLIC]
    assert not private, (
        f"book/api.md names modules that are not public slamlib modules: {private}"
    )
    excluded = [m for m in EXCLUDED if m in DOCUMENTED]
    assert not excluded, f"modules both excluded and documented: {excluded}"


@pytest.mark.parametrize("package", PACKAGES)
def test_a_package_documents_only_what_it_defines(package):
    """Re-exports documented on the package too would be "duplicate object description" warnings; what the
    package defines itself (``make_map``, ``get_backend``, a constant with a ``#:`` docstring) must be named in its
    ``:members:``, or it is missing from the reference."""
    options = DOCUMENTED.get(package, [])
    listed = [o for o in options if o.startswith(":members:")]
    names = {
        n.strip()
        for o in listed
        for n in o.removeprefix(":members:").split(",")
        if n.strip()
    }
    assert not listed or names, (
        f"{package}: a bare :members: documents every re-export again"
    )
    module = importlib.import_module(package)
    own = {
        name
        for name, obj in vars(module).items()
        if not name.startswith("_")
        and (inspect.isfunction(obj) or inspect.isclass(obj))
        and obj.__module__ == package
    }
    own |= {
        name
        for cls, name in ModuleAnalyzer.for_module(package).find_attr_docs()
        if not cls
    }
    assert own <= names, (
        f"{package} defines {sorted(own - names)}: list them in its :members:"
    )
    assert names <= own, (
        f"{package}: {sorted(names - own)} are re-exports, documented on their modules"
    )
