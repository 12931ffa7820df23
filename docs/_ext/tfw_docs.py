"""Small Sphinx helpers for the torchfluidwarp documentation.

* ``.. if-exists:: PATH`` / ``.. if-missing:: PATH``: parse the directive's content only if ``PATH``
  (relative to the repository root) exists / does not exist. Pages use them to link gallery examples and
  pages of modules that other work is still adding, without leaving a broken link when they are absent.
  The page depends on ``PATH``, so an incremental build re-reads it when the file appears or goes. The
  content cannot hold section titles (they would nest under the current section): keep titles outside.
* ``.. cli-subcommands:: MODULE FUNC``: the command-line page, one sphinx-argparse section per subcommand,
  with terminal-formatted epilogs shown verbatim.
* :func:`gif_scraper`: a sphinx-gallery image scraper that picks up the GIFs an example writes into its
  working directory (the ``examples/`` folder) with :func:`torchfluidwarp.io.write_animation`, moves them
  into the gallery's image folder and shows them on the example's page.
* :func:`reset_example`: run before every example: restores torch's global grad mode, which a careless
  example could leave off for the ones after it (they all run in one process), and notes the start time.
* :func:`_reexported`: a cross-reference to a name where a subpackage re-exports it
  (``torchfluidwarp.morph.morph``) resolves to the page of the module that defines it
  (``torchfluidwarp.morph.morphing.morph``): the API pages document each object once, where it lives.
"""

from __future__ import annotations

import argparse
import importlib
import inspect
import re
import shutil
import time
from pathlib import Path

from docutils import nodes
from docutils.parsers.rst import directives
from sphinx.application import Sphinx
from sphinx.util import logging
from sphinx.util.docutils import SphinxDirective

ROOT = Path(__file__).resolve().parents[2]
_started: dict[str, float] = {}
_log = logging.getLogger(__name__)


class _IfPath(SphinxDirective):
    has_content = True
    required_arguments = 1
    final_argument_whitespace = False
    want: bool = True

    def run(self) -> list[nodes.Node]:
        path = ROOT / self.arguments[0]
        self.env.note_dependency(str(path))
        if path.exists() != self.want:
            return []
        return self.parse_content_to_nodes()


class IfExists(_IfPath):
    """``.. if-exists:: path``: the content, if the path exists."""

    want = True


class IfMissing(_IfPath):
    """``.. if-missing:: path``: the content, if the path does not exist."""

    want = False


_MD_LINK = re.compile(r"\[([^\]]+)\]\((\.\./[^)\s#]+)(#[^)\s]*)?\)")


def _outside_links(app: Sphinx, docname: str, source: list[str]) -> None:
    """Turn Markdown links to repository files outside ``docs/`` into their text and path.

    ``docs/benchmarks.md`` is written for reading on a code host, where ``../benchmarks/README.md`` is a
    file; the site has no page for it, and MyST would report a missing cross-reference.
    """
    if not app.env.doc2path(docname).suffix == ".md":
        return
    here = Path(app.env.doc2path(docname)).parent

    def replace(match: re.Match[str]) -> str:
        target = (here / match.group(2)).resolve()
        if target.is_relative_to(Path(app.srcdir).resolve()) or not target.exists():
            return match.group(0)
        return f"{match.group(1)} (`{target.relative_to(ROOT).as_posix()}` in the repository)"

    source[0] = _MD_LINK.sub(replace, source[0])


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


class CliSubcommands(SphinxDirective):
    """``.. cli-subcommands:: MODULE FUNC``: one section per subcommand of the parser ``MODULE.FUNC()``.

    Each section is sphinx-argparse's ``.. argparse::`` for that subcommand. An epilog written for the
    terminal (a parser with ``RawDescriptionHelpFormatter``) is shown as a literal block instead of being
    parsed as reST, which would mangle its layout and quotes. New subcommands appear without editing the page.
    """

    required_arguments = 2
    option_spec = {"prog": directives.unchanged}

    def run(self) -> list[nodes.Node]:
        module, func = self.arguments
        parser = getattr(importlib.import_module(module), func)()
        prog = self.options.get("prog", parser.prog)
        lines: list[str] = []
        for action in parser._actions:
            if not isinstance(action, argparse._SubParsersAction):
                continue
            for name, sub in action.choices.items():
                title = f"``{prog} {name}``"
                lines += [
                    title,
                    "-" * len(title),
                    "",
                    ".. argparse::",
                    f"   :module: {module}",
                    f"   :func: {func}",
                    f"   :prog: {prog}",
                    f"   :path: {name}",
                ]
                raw = issubclass(sub.formatter_class, argparse.RawDescriptionHelpFormatter)
                if raw and sub.epilog:
                    lines += ["   :noepilog:", "", ".. code-block:: text", ""]
                    lines += ["   " + line for line in sub.epilog.splitlines()]
                lines.append("")
        return self.parse_text_to_nodes("\n".join(lines), allow_section_headings=True)


_MISSING, _FIELD = object(), object()


def _lookup(target: str) -> object:
    """The object a dotted ``target`` names (a module path, then attributes), or ``_MISSING``."""
    parts = target.split(".")
    for cut in range(len(parts), 0, -1):
        try:
            obj: object = importlib.import_module(".".join(parts[:cut]))
        except ImportError:
            continue
        for i, name in enumerate(parts[cut:]):
            try:
                owner, obj = obj, getattr(obj, name, _MISSING)
            except Exception:  # noqa: BLE001 - a lazy attribute whose import fails (an optional dependency)
                return _FIELD  # exists, but cannot be looked at here: leave it to Sphinx
            if obj is _MISSING:  # an attribute set in __init__ or a dataclass field: documented, not on the class
                last = cut + i == len(parts) - 1
                return _FIELD if last and isinstance(owner, type) and _documents(owner, name) else _MISSING
        return obj
    return _MISSING


def _documents(cls: type, name: str) -> bool:
    """Whether class ``cls`` has an instance attribute ``name``: a dataclass field without a default (an
    annotation), or an entry of its docstring's ``Attributes:`` section (set in ``__init__``)."""
    if any(name in getattr(k, "__annotations__", {}) for k in cls.__mro__):
        return True
    return re.search(rf"^\s+{re.escape(name)}( \(.*\))?:", inspect.getdoc(cls) or "", re.MULTILINE) is not None


def _reexported(app: Sphinx, env, node, contnode):  # noqa: ANN001 - Sphinx's missing-reference signature
    """Resolve a Python cross-reference to a re-exported ``torchfluidwarp`` name by where it is defined, and warn
    of one to a name that does not exist (a renamed or moved function: without ``nitpicky``, Sphinx would show
    it as plain text in silence)."""
    target = node.get("reftarget", "")
    if node.get("refdomain") != "py" or not target.startswith("torchfluidwarp."):
        return None
    obj = _lookup(target)
    if obj is _MISSING:
        _log.warning("cross-reference to %s, which does not exist", target, location=node)
        return None
    if obj is _FIELD:
        return None
    module, qualname = getattr(obj, "__module__", None), getattr(obj, "__qualname__", None)
    if not isinstance(module, str) or not isinstance(qualname, str) or "<" in qualname:
        return None
    canonical = f"{module}.{qualname}"
    if canonical == target:
        return None
    domain = env.get_domain("py")
    return domain.resolve_xref(env, node["refdoc"], app.builder, node["reftype"], canonical, node, contnode)


def setup(app: Sphinx) -> dict[str, object]:
    app.add_directive("if-exists", IfExists)
    app.add_directive("if-missing", IfMissing)
    app.add_directive("cli-subcommands", CliSubcommands)
    app.connect("source-read", _outside_links)
    app.connect("missing-reference", _reexported)
    return {"parallel_read_safe": True, "parallel_write_safe": True}
