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
copyright = "2026, the ltv_lstm_mpc developers"

from ltv_lstm_mpc import __version__  # noqa: E402

version = release = __version__

extensions = [
    "sphinx.ext.autodoc",
    "sphinx.ext.autosummary",
    "sphinx.ext.napoleon",
    "sphinx.ext.mathjax",
    # MathJax 3 from the package, copied into _build/html/_static/mathjax: math renders
    # offline (sphinx.ext.mathjax alone loads it from a CDN)
    "sphinx-mathjax-offline",
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
nitpick_ignore_regex = [
    (r"py:.*", r"^(?!ltv_lstm_mpc\b).*"),
    # private names (a leading underscore) and numba's structref types have no pages
    (r"py:.*", r".*\._[A-Za-z].*"),
    (r"py:.*", r".*(Workspace|Arrays)Type$"),
    (r"py:(class|obj)", r"ltv_lstm_mpc\.(validation|deferred_state)\.T"),  # TypeVars
]

sphinx_gallery_conf = {
    "examples_dirs": "examples",
    "gallery_dirs": "gallery",
    "filename_pattern": r"/plot_",
    "download_all_examples": False,
    "remove_config_comments": True,
    "reference_url": {"ltv_lstm_mpc": None},
    # no sg_execution_times pages: they hold the build machine's timings and load jQuery
    # and DataTables from CDNs (docs/check_links.py refuses both)
    "write_computation_times": False,
}

# Solvers the gallery's controllers use: their compiled kernels are compiled (or loaded from
# numba's cache) before the examples run, so no example's output shows the build machine's
# cache state ("compiling ...", "... compile in the background"); docs/check_links.py fails
# the build's check if a gallery page still holds such a notice (a solver missing here).
GALLERY_SOLVERS = ["daqp", "clarabel", "osqp", "quadprog", "cvxpy:CLARABEL", "cvxpy:ECOS"]


def _warm_up_gallery_kernels() -> None:
    """``ltv-lstm-mpc warmup`` for :data:`GALLERY_SOLVERS` in a child process; its output
    goes to the build log, not into a page."""
    import subprocess

    from sphinx.util import logging

    logger = logging.getLogger("ltv_lstm_mpc.docs")
    argv = ["warmup", *(f"--solver={solver}" for solver in GALLERY_SOLVERS)]
    code = f"import sys; from ltv_lstm_mpc.cli.main import main; sys.exit(main({argv!r}))"
    done = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, check=False
    )
    for line in (done.stdout + done.stderr).splitlines():
        logger.info("[warmup] %s", line)
    if done.returncode != 0:
        logger.warning("ltv-lstm-mpc warmup exited %d (see [warmup] above)", done.returncode)


html_theme = "pydata_sphinx_theme"
html_title = f"ltv_lstm_mpc {version}"
html_theme_options = {
    "navigation_depth": 2,
    "show_toc_level": 2,
}


def _write_modules_page() -> None:
    """``modules.rst``: every module with its description and the members not already on
    an API page (the names re-exported by ``ltv_lstm_mpc`` / ``ltv_lstm_mpc.solvers`` have
    their page there, so each object is documented once)."""
    import importlib

    import ltv_lstm_mpc.solvers as solvers

    import ltv_lstm_mpc

    exported: dict[int, str] = {}
    for package in (ltv_lstm_mpc, solvers):
        for name in package.__all__:
            exported[id(getattr(package, name))] = name
    names = []
    for folder, prefix in (
        (ROOT / "ltv_lstm_mpc", "ltv_lstm_mpc"),
        (ROOT / "solvers", "ltv_lstm_mpc.solvers"),
    ):
        for path in sorted(folder.rglob("*.py")):
            parts = list(path.relative_to(folder).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts = parts[:-1]
            if any(part.startswith("_") for part in parts) or parts[-1:] == ["__main__"]:
                continue
            names.append(".".join([prefix, *parts]))
    lines = [
        "Modules",
        "=======",
        "",
        "Every module of the library with its description; the docstrings name the paper's",
        "equations and the items of the :doc:`paper notes <paper-notes>` they implement. Names",
        "that ``ltv_lstm_mpc`` or ``ltv_lstm_mpc.solvers`` export have their page in the",
        ":doc:`API reference <api>`.",
        "",
    ]
    for module_name in names:
        if module_name in ("ltv_lstm_mpc", "ltv_lstm_mpc.solvers"):
            continue
        module = importlib.import_module(module_name)
        public = getattr(module, "__all__", None)
        if public is None:
            public = [n for n, v in vars(module).items() if not n.startswith("_")
                      and getattr(v, "__module__", None) == module_name]  # fmt: skip
        excluded = sorted(n for n in public if id(getattr(module, n, None)) in exported)
        package = hasattr(module, "__path__")  # its names are its modules' (listed below)
        lines += [f"``{module_name}``", "-" * (len(module_name) + 4), "",
                  f".. automodule:: {module_name}",
                  "   :no-members:" if package else "   :members:"]  # fmt: skip
        if excluded and not package:
            lines.append(f"   :exclude-members: {', '.join(excluded)}")
        lines.append("")
    text = "\n".join(lines)
    page = Path(__file__).with_name("modules.rst")
    if not page.exists() or page.read_text() != text:
        page.write_text(text)


_write_modules_page()
_warm_up_gallery_kernels()
