"""Sphinx configuration of the rollbot_oc docs (``make docs``: docs/_build/html, warnings are errors).

Why Sphinx: the API reference comes from the numpydoc docstrings (autodoc + napoleon), as python-control's and
do-mpc's do; MyST lets every guide be Markdown; myst-nb renders the notebooks with their outputs. Two pages are
written at build time by ``_ext/rollbot_docs.py``: the API reference (one page per module found by walking the
installed package, so it follows any module layout) and the benchmarks page (from ``benchmarks/*_result*``).
"""

import os
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE / "_ext"))
sys.path.insert(0, str(HERE.parent))  # the checkout's rollbot_oc, also when not installed

project = "rollbot_oc"
author = "rollbot_oc developers"
copyright = "rollbot_oc developers, MIT licence"

extensions = [
    "myst_nb",                  # Markdown (MyST) pages and Jupyter notebooks
    "sphinx.ext.autodoc",
    "sphinx.ext.napoleon",      # numpydoc docstrings
    "sphinx.ext.autosummary",
    "sphinx.ext.mathjax",
    "sphinxcontrib.mermaid",    # the NMPC's mode diagrams
    "rollbot_docs",             # API stubs and the benchmarks page, written at build time
]
source_suffix = {".rst": "restructuredtext", ".md": "myst-nb", ".ipynb": "myst-nb"}
exclude_patterns = ["_build", "_ext", "Thumbs.db", ".DS_Store", "**/.ipynb_checkpoints", "make_modes.py"]

# MyST: $...$ and $$...$$ maths, ::: fences, heading anchors for links inside pages; ```mermaid fences are diagrams
myst_enable_extensions = ["dollarmath", "amsmath", "colon_fence", "deflist"]
myst_heading_anchors = 3
myst_fence_as_directive = ["mermaid"]

# Notebooks: stored without outputs. `make docs` runs each once in quick mode (ROLLBOT_QUICK=1, the mode the
# notebook tests use) and caches the result (docs/_build/.jupyter_cache): a notebook runs again only when its
# code changes. NB_EXECUTION_MODE=off (the docs test) renders them without running them.
nb_execution_mode = os.environ.get("NB_EXECUTION_MODE", "cache")
nb_execution_cache_path = str(HERE / "_build" / ".jupyter_cache")
nb_execution_timeout = 1200
nb_execution_raise_on_error = True
nb_merge_streams = True
os.environ.setdefault("ROLLBOT_QUICK", "1")
os.environ.setdefault("MPLBACKEND", "module://matplotlib_inline.backend_inline")

# API reference: numpydoc through napoleon; members in source order; only what a module defines itself (so a
# module that re-exports names from their new home does not document them twice)
napoleon_google_docstring = False
napoleon_numpy_docstring = True
napoleon_use_rtype = False
napoleon_use_ivar = True  # an Attributes section lists fields; autodoc does not document them a second time
autodoc_default_options = {"members": True, "undoc-members": False, "show-inheritance": True,
                           "member-order": "bysource", "ignore-module-all": True}
autodoc_typehints = "description"
autodoc_typehints_format = "short"
autosummary_generate = False
nitpicky = False

html_theme = "furo"
html_title = "rollbot_oc"
html_static_path = []
html_show_sourcelink = False
# A name in a docstring's type field that several classes define as an attribute (N, omega0, points, ...) links
# to one of them; Sphinx warns of the ambiguity, which is not an error of the docs.
suppress_warnings = ["ref.python"]
