"""Sphinx configuration of the nanosim documentation (``sphinx-build -W -b html docs docs/_build/html``)."""
from __future__ import annotations

import os
import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))     # conf._held_figures, the gallery scraper
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("MPLBACKEND", "Agg")

import nanosim  # noqa: E402

project = "nanosim"
author = "nanosim developers"
copyright = "nanosim developers"
release = version = nanosim.__version__

extensions = [
    "sphinx.ext.autodoc",
    "sphinx.ext.autosummary",
    "sphinx.ext.mathjax",
    "sphinx.ext.viewcode",
    "numpydoc",
    "myst_parser",
    "sphinxarg.ext",
    "sphinx_gallery.gen_gallery",
]

source_suffix = {".rst": "restructuredtext", ".md": "markdown"}
exclude_patterns = ["_build", "auto_examples/*.ipynb", "auto_examples/*.py", "auto_examples/*.zip",
                    "auto_examples/*.md5", "auto_examples/*.json"]
myst_enable_extensions = ["dollarmath", "colon_fence", "deflist"]
myst_heading_anchors = 3

# API reference: one page per module, generated from the docstrings.
autosummary_generate = True
autosummary_imported_members = False
autodoc_default_options = {"members": True, "show-inheritance": False, "ignore-module-all": True}
autodoc_typehints = "none"
autodoc_member_order = "bysource"
numpydoc_show_class_members = False
numpydoc_class_members_toctree = False
numpydoc_validation_checks: set = set()
numpydoc_xref_param_type = False
# Docstrings describe array shapes and physical units in their type fields; they are prose, not targets.
nitpicky = False
suppress_warnings = ["autosummary.import_cycle"]

sphinx_gallery_conf = {
    "examples_dirs": str(ROOT / "examples"),
    "gallery_dirs": "auto_examples",
    "filename_pattern": r"/plot_",
    "within_subsection_order": "FileNameSortKey",
    "download_all_examples": False,
    "remove_config_comments": True,
    "abort_on_example_error": True,
    "show_memory": False,
    "matplotlib_animations": False,
    "reset_modules": ("matplotlib",),
    "image_scrapers": ("matplotlib", "conf._held_figures"),
}

html_theme = "furo"
html_title = f"nanosim {release}"
html_static_path: list = []
templates_path: list = []


# Docstrings write absolute values and norms as |x| (numpy and scipy do the same); in reST a bar pair
# is a substitution reference, so it is shown literally instead.
_BARS = re.compile(r"(?<![|\\`])\|(?=[^\s|])([^|\n`]*?[^\s|])\|(?![|_])")
# A class docstring whose second paragraph is a ``name : description`` list documents its fields.
_FIELD = re.compile(r"^\w[\w, ]* : ")
_SECTION = ("Attributes", "Parameters", "Returns", "Notes", "Examples", "Methods", "See Also")


def _is_table_row(line: str) -> bool:
    t = line.strip()
    return t.startswith("+-") or (t.startswith("|") and t.endswith("|") and t.count("|") > 2)


def _prepare_docstring(app, what, name, obj, options, lines):
    for i, line in enumerate(lines):
        if not _is_table_row(line):
            lines[i] = _BARS.sub(lambda m: "\\|" + m.group(1) + "\\|", line)
    # autosummary ends a summary at the first ". "; an ellipsis inside a literal is not a sentence end
    for i, line in enumerate(lines):
        if not line.strip():
            break
        lines[i] = line.replace(" ... ", " \u2026 ").replace(" .. ", " \u2026 ")
    if what == "class" and not any(line.strip() in _SECTION for line in lines):
        try:
            k = lines.index("") + 1
        except ValueError:
            return
        if k < len(lines) and _FIELD.match(lines[k]):
            lines[k:k] = ["Attributes", "----------"]


# nanosim's plotting functions return pyplot-free Figures (nanosim.plots never touches global state);
# the gallery shows every Figure an example holds in a variable, once, in the order they appear.
_SHOWN: dict = {}


def _figures_in(value):
    from matplotlib.figure import Figure

    if isinstance(value, Figure):
        yield value
    elif isinstance(value, (list, tuple)):
        for v in value:
            yield from _figures_in(v)
    elif isinstance(value, dict):
        for v in value.values():
            yield from _figures_in(v)


def _held_figures(block, block_vars, gallery_conf, **kwargs):
    from sphinx_gallery.scrapers import figure_rst

    shown = _SHOWN.setdefault(block_vars["src_file"], set())
    paths = []
    for name, value in list(block_vars["example_globals"].items()):
        if name.startswith("_"):
            continue
        for fig in _figures_in(value):
            if id(fig) in shown or getattr(fig, "number", None) is not None:
                continue        # already shown, or a pyplot figure (the matplotlib scraper's)
            shown.add(id(fig))
            path = next(block_vars["image_path_iterator"])
            fig.savefig(path, dpi=90)
            paths.append(path)
    return figure_rst(paths, gallery_conf["src_dir"])


def setup(app):
    """Connect the docstring preparation (before numpydoc, priority 500, turns the sections into reST)."""
    app.connect("autodoc-process-docstring", _prepare_docstring, priority=400)
