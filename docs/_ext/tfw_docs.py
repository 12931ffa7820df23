"""Small Sphinx helpers for the torchfluidwarp documentation.

* ``.. if-exists:: PATH`` / ``.. if-missing:: PATH``: parse the directive's content only if ``PATH``
  (relative to the repository root) exists / does not exist. Pages use them to link gallery examples and
  pages of modules that other work is still adding, without leaving a broken link when they are absent.
  The page depends on ``PATH``, so an incremental build re-reads it when the file appears or goes.
* :func:`gif_scraper`: a sphinx-gallery image scraper that picks up the GIFs an example writes into its
  working directory (the ``examples/`` folder) with :func:`torchfluidwarp.io.write_animation`, moves them
  into the gallery's image folder and shows them on the example's page.
* :func:`reset_example`: run before every example: restores torch's global grad mode, which a careless
  example could leave off for the ones after it (they all run in one process), and notes the start time.
"""

from __future__ import annotations

import shutil
import time
from pathlib import Path

from docutils import nodes  # noqa: F401 - for the type hints
from docutils.parsers.rst import directives
from sphinx.application import Sphinx
from sphinx.util.docutils import SphinxDirective

ROOT = Path(__file__).resolve().parents[2]
_started: dict[str, float] = {}


class _IfPath(SphinxDirective):
    has_content = True
    required_arguments = 1
    final_argument_whitespace = False
    option_spec = {"any": directives.unchanged}
    want: bool = True

    def run(self) -> list[nodes.Node]:
        path = ROOT / self.arguments[0]
        self.env.note_dependency(str(path))
        if path.exists() != self.want:
            return []
        return self.parse_content_to_nodes(allow_section_headings=True)


class IfExists(_IfPath):
    """``.. if-exists:: path``: the content, if the path exists."""

    want = True


class IfMissing(_IfPath):
    """``.. if-missing:: path``: the content, if the path does not exist."""

    want = False


def reset_example(gallery_conf, fname, when=None):  # noqa: ARG001 - sphinx-gallery's signature
    import torch

    torch.set_grad_enabled(True)
    _started[str(fname)] = time.time()


def gif_scraper(block, block_vars, gallery_conf):  # noqa: ARG001 - sphinx-gallery's signature
    """Move the GIFs written by the running example into the gallery and return their reST."""
    from sphinx_gallery.scrapers import figure_rst

    src = Path(block_vars["src_file"])
    since = _started.get(src.name, _started.get(str(src), 0.0)) - 1.0
    found = sorted(p for p in src.parent.glob("*.gif") if p.stat().st_mtime >= since)
    images = []
    for gif in found:
        target = Path(next(block_vars["image_path_iterator"])).with_suffix(".gif")
        shutil.move(gif, target)
        images.append(str(target))
    if not images:
        return ""
    return figure_rst(images, gallery_conf["src_dir"])


def setup(app: Sphinx) -> dict[str, object]:
    app.add_directive("if-exists", IfExists)
    app.add_directive("if-missing", IfMissing)
    return {"parallel_read_safe": True, "parallel_write_safe": True}
