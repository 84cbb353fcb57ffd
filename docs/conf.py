"""Sphinx configuration of the ltv_lstm_mpc documentation site.

Build: ``python -m sphinx -b html docs docs/_build/html`` (the README's docs command); the
gallery under ``docs/examples`` runs at build time and embeds its figures.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
os.environ.setdefault("MPLBACKEND", "Agg")

project = "ltv_lstm_mpc"
author = "the ltv_lstm_mpc developers"
copyright = "2026, the ltv_lstm_mpc developers"  # noqa: A001 - Sphinx's name

from ltv_lstm_mpc import __version__  # noqa: E402

version = release = __version__

extensions = [
    "sphinx.ext.autodoc",
    "sphinx.ext.autosummary",
    "sphinx.ext.napoleon",
    "sphinx.ext.mathjax",
    "sphinx.ext.viewcode",
    "myst_parser",
    "sphinx_gallery.gen_gallery",
]

source_suffix = {".rst": "restructuredtext", ".md": "markdown"}
exclude_patterns = ["_build", "examples/README.rst"]
templates_path = ["_templates"]

# numpy-style docstrings (napoleon), one page per public name (autosummary)
autosummary_generate = True
autosummary_imported_members = True
autodoc_default_options = {"members": True, "show-inheritance": True}
autodoc_typehints = "description"
autodoc_member_order = "bysource"
napoleon_google_docstring = False
napoleon_numpy_docstring = True
napoleon_use_rtype = False
napoleon_use_ivar = True  # dataclass fields: documented in place, not cross-referenced

myst_enable_extensions = ["dollarmath"]
myst_heading_anchors = 3

# Nitpicky cross-references for the project's own names only (array shapes such as "(2n,)"
# and third-party types are not pages of this site).
nitpick_ignore_regex = [(r"py:.*", r"^(?!ltv_lstm_mpc\b).*")]

sphinx_gallery_conf = {
    "examples_dirs": "examples",
    "gallery_dirs": "gallery",
    "filename_pattern": r"/plot_",
    "download_all_examples": False,
    "remove_config_comments": True,
    "reference_url": {"ltv_lstm_mpc": None},
}

html_theme = "pydata_sphinx_theme"
html_title = f"ltv_lstm_mpc {version}"
html_theme_options = {
    "navigation_depth": 2,
    "show_toc_level": 2,
}
