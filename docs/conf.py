"""Sphinx configuration of the torchfluidwarp documentation.

Build (from the repository root; needs ``pip install -e ".[docs]"``)::

    python -m sphinx -W --keep-going -b html docs docs/_build/html

The build is offline: no intersphinx, no fonts or scripts from a CDN. sphinx-gallery runs every
``examples/plot_*.py`` during the build (in this process, one after the other).
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

DOCS = Path(__file__).resolve().parent
ROOT = DOCS.parent
sys.path.insert(0, str(DOCS / "_ext"))
sys.path.insert(0, str(ROOT))

# One torch thread for the examples: on small shared machines the default (one per core) can make small
# matrix products orders of magnitude slower when another process holds a core (see docs/benchmarks.md).
os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("MPLBACKEND", "agg")

import torch  # noqa: E402

import torchfluidwarp  # noqa: E402

torch.set_num_threads(int(os.environ["OMP_NUM_THREADS"]))

# -- project --------------------------------------------------------------------------------------------
project = "torchfluidwarp"
author = "the torchfluidwarp authors"
copyright = "the torchfluidwarp authors"  # noqa: A001 - Sphinx's name
release = torchfluidwarp.__version__
version = release

# -- extensions -----------------------------------------------------------------------------------------
extensions = [
    "sphinx.ext.autodoc",
    "sphinx.ext.autosummary",
    "sphinx.ext.napoleon",
    "sphinx.ext.viewcode",
    "sphinx_gallery.gen_gallery",
    "sphinx_copybutton",
    "sphinxarg.ext",
    "myst_parser",
    "tfw_docs",
]

source_suffix = {".rst": "restructuredtext", ".md": "markdown"}
root_doc = "index"
exclude_patterns = [
    "_build",
    "Thumbs.db",
    ".DS_Store",
    "auto_examples/*.ipynb",
    "auto_examples/*.py",
    "auto_examples/*.zip",
]
templates_path = ["_templates"]
highlight_language = "none"  # "::" blocks are usage texts, JSON or shapes; Python blocks say so

# -- autodoc / napoleon ---------------------------------------------------------------------------------
autosummary_generate = True
autodoc_member_order = "bysource"
autodoc_typehints = "signature"
autodoc_typehints_format = "short"
autodoc_preserve_defaults = False  # True fails ("pop from empty list") on RandomFluidWarp after the gallery has run
autodoc_inherit_docstrings = False  # torch and torchvision docstrings say nothing about our overrides
autodoc_class_signature = "mixed"
napoleon_google_docstring = True
napoleon_numpy_docstring = False
napoleon_use_ivar = True  # dataclass "Attributes:" as fields, not as duplicate attribute entries
napoleon_use_rtype = False
napoleon_attr_annotations = True

# -- myst (docs/benchmarks.md, the changelog and contributing guide) ------------------------------------
myst_enable_extensions = ["colon_fence"]
myst_heading_anchors = 3

# -- sphinx-gallery -------------------------------------------------------------------------------------
sphinx_gallery_conf = {
    "examples_dirs": str(ROOT / "examples"),
    "gallery_dirs": "auto_examples",
    "filename_pattern": r"/plot_",
    "ignore_pattern": r"__init__\.py|/_",
    "within_subsection_order": "FileNameSortKey",
    "image_scrapers": ("matplotlib", "tfw_docs.gif_scraper"),
    "reset_modules": ("matplotlib", "tfw_docs.reset_example"),
    "backreferences_dir": "gen_modules/backreferences",
    "doc_module": ("torchfluidwarp",),
    "write_computation_times": False,  # its page loads jQuery from a CDN
    "download_all_examples": False,
    "show_memory": False,
    "remove_config_comments": True,
    "abort_on_example_error": False,
    "only_warn_on_example_error": False,
    "capture_repr": ("_repr_html_", "__repr__"),
    "matplotlib_animations": False,
    "thumbnail_size": (320, 224),
    "show_signature": False,
}

# -- HTML -----------------------------------------------------------------------------------------------
html_theme = "furo"
html_title = f"torchfluidwarp {release}"
html_static_path = ["_static"]
html_css_files = ["custom.css"]
html_theme_options = {"navigation_with_keys": True}
html_last_updated_fmt = None
html_show_sourcelink = False
copybutton_prompt_text = r">>> |\.\.\. |\$ "
copybutton_prompt_is_regexp = True
