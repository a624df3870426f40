"""Sphinx extension: attribute, constant and property docstrings rendered as written, not split by napoleon.

napoleon reads the first line of such a docstring as ``type: description`` and moves the words before its first
colon into a "Type" field. slamlib's are prose whose first line often holds a colon ("Exit codes of a command
ended by a signal, as a shell reports them: 128 + SIGINT ..."), so the reference would show the sentence's end
first and its start as a type. This extension puts a line without a colon in front of each such docstring just
before napoleon runs (so napoleon finds no type but still converts any numpy sections) and takes it away just
after. Listed in _config.yml (``local_extensions`` and ``sphinx.config.extensions``).
"""

_WHAT = ("attribute", "data", "property")
_SENTINEL = "PROSE-ATTRIBUTE-DOCSTRING"
#: sphinx.ext.napoleon connects ``autodoc-process-docstring`` at Sphinx's default priority.
_NAPOLEON_PRIORITY = 500


def _guard(app, what, name, obj, options, lines):
    if what in _WHAT and any(line.strip() for line in lines):
        lines.insert(0, _SENTINEL)


def _unguard(app, what, name, obj, options, lines):
    if what not in _WHAT:
        return
    for i, line in enumerate(lines):
        if line.strip():
            if line.strip() == _SENTINEL:
                del lines[i]
            return


def setup(app):
    app.setup_extension("sphinx.ext.napoleon")
    app.connect("autodoc-process-docstring", _guard, priority=_NAPOLEON_PRIORITY - 1)
    app.connect("autodoc-process-docstring", _unguard, priority=_NAPOLEON_PRIORITY + 1)
    return {"parallel_read_safe": True, "parallel_write_safe": True}
