"""The layout's boundaries (issue #30): a subpackage's private names stay inside it, no ``import *``, no
compatibility layer, and no process-wide caches in the core and the warp.

The checks read the source with :mod:`ast`; each checker is also run on small synthetic sources, so that a
checker which finds nothing cannot pass whatever the code does.

The rule for private names: a module of ``torchfluidwarp/<sub>/`` may import a private name (``_x``, not a
dunder) or a private module only from ``torchfluidwarp/<sub>/``; a top-level module of the package is its own
``<sub>``. ``torchfluidwarp._checks`` and ``torchfluidwarp._version`` are the package's shared internals: any
module of the package may import them (not the private names inside them). ``benchmarks/`` and ``examples/``
use the public API only: no private name of ``torchfluidwarp`` at all. Reaching a private name through an
imported module (``from torchfluidwarp.warp import maps; maps._raster(...)``) counts as importing it.
"""

from __future__ import annotations

import ast
import importlib
import pathlib
from collections.abc import Iterator

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "torchfluidwarp"
CLIENTS = ["benchmarks", "examples"]  # use the public API only
SHARED = {"torchfluidwarp._checks", "torchfluidwarp._version"}
"""The package-level internals that every module of the package may import."""

NO_CACHES = ["core", "warp"]
"""Subpackages whose constants belong to the objects that use them (a grid, a simulator), never to the process."""

FLAT_LAYOUT = [
    "torchfluidwarp.grid",
    "torchfluidwarp.spectral",
    "torchfluidwarp.linalg",
    "torchfluidwarp.fluid",
    "torchfluidwarp.simulator",
    "torchfluidwarp.sampling",
    "torchfluidwarp.spline",
    "torchfluidwarp.forces",
    "torchfluidwarp.optim",
    "torchfluidwarp.registration",
    "torchfluidwarp.alignment",
    "torchfluidwarp.augment_tv",
    "torchfluidwarp.animate_config",
    "torchfluidwarp.cli",
    "torchfluidwarp.studio",
]
"""The module paths of the flat layout, for which ``torchfluidwarp._compat`` installed stand-ins until #30."""


# ---- the checkers ---------------------------------------------------------------------------------------------


def _is_private(name: str) -> bool:
    return name.startswith("_") and not name.endswith("__")


def _unit(module: str) -> str | None:
    """The part of the package whose privates ``module`` may share: ``torchfluidwarp.<sub>`` (a subpackage or a
    top-level module), ``torchfluidwarp`` for the top level itself, ``None`` outside the package."""
    parts = module.split(".")
    return ".".join(parts[:2]) if parts[0] == "torchfluidwarp" else None


def _allowed(target: str, owner: str | None) -> bool:
    """Whether a module of ``owner`` (see :func:`_unit`) may import the dotted name ``target``."""
    parts = target.split(".")
    if parts[0] != "torchfluidwarp":
        return True
    private = [i for i, part in enumerate(parts) if _is_private(part)]
    if not private:
        return True
    if owner is None:  # benchmarks, examples: the public API only
        return False
    unit = ".".join(parts[:2])
    return unit == owner or (unit in SHARED and private == [1])


def _absolute(node: ast.ImportFrom, module: str, is_package: bool) -> str:
    if node.level == 0:
        return node.module or ""
    base = module.split(".") if is_package else module.split(".")[:-1]
    base = base[: len(base) - (node.level - 1)]
    return ".".join(base + ([node.module] if node.module else []))


def private_imports(source: str, module: str, *, is_package: bool = False) -> list[str]:
    """The private names of ``torchfluidwarp`` that ``source`` (the text of ``module``) imports, or reaches
    through an imported module, against the rule of this file: ``["line 12: torchfluidwarp.core.advection._geo",
    ...]``."""
    tree = ast.parse(source)
    owner = _unit(module)
    found: dict[str, None] = {}  # ordered, without repeats
    aliases: dict[str, str] = {}  # a bound name -> the dotted path of what it holds

    def check(target: str, line: int) -> None:
        if not _allowed(target, owner):
            parts = target.split(".")
            last = max(i for i, part in enumerate(parts) if _is_private(part))
            found[f"line {line}: {'.'.join(parts[: last + 1])}"] = None  # up to the private name

    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                check(alias.name, node.lineno)
                if alias.asname:
                    aliases[alias.asname] = alias.name
                else:
                    aliases[alias.name.split(".")[0]] = alias.name.split(".")[0]
        elif isinstance(node, ast.ImportFrom):
            base = _absolute(node, module, is_package)
            for alias in node.names:
                if alias.name != "*":
                    target = f"{base}.{alias.name}"
                    check(target, node.lineno)
                    aliases[alias.asname or alias.name] = target
    aliases = {k: v for k, v in aliases.items() if v.split(".")[0] == "torchfluidwarp"}
    for node in ast.walk(tree):
        if isinstance(node, ast.Attribute):
            chain, value = [], node
            while isinstance(value, ast.Attribute):
                chain.append(value.attr)
                value = value.value
            if isinstance(value, ast.Name) and value.id in aliases:
                check(".".join([aliases[value.id], *reversed(chain)]), node.lineno)
    return list(found)


def star_imports(source: str) -> list[str]:
    """``from x import *`` in ``source``: ``["line 3: from x import *", ...]``."""
    return [
        f"line {node.lineno}: from {'.' * node.level}{node.module or ''} import *"
        for node in ast.walk(ast.parse(source))
        if isinstance(node, ast.ImportFrom) and any(alias.name == "*" for alias in node.names)
    ]


def process_caches(source: str) -> list[str]:
    """``functools.lru_cache`` / ``functools.cache`` used outside a function body: on a module-level function, a
    method or at module level, where the cache lives as long as the process."""
    tree = ast.parse(source)
    modules = {"functools"}  # names bound to the functools module
    caches: set[str] = set()  # names bound to its caches
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            modules |= {alias.asname or alias.name for alias in node.names if alias.name == "functools"}
        elif isinstance(node, ast.ImportFrom) and node.module == "functools":
            caches |= {alias.asname or alias.name for alias in node.names if alias.name in ("lru_cache", "cache")}
    found: list[str] = []

    def is_cache(node: ast.AST) -> bool:
        if isinstance(node, ast.Name):
            return node.id in caches
        return (
            isinstance(node, ast.Attribute)
            and node.attr in ("lru_cache", "cache")
            and isinstance(node.value, ast.Name)
            and node.value.id in modules
        )

    def visit(node: ast.AST) -> None:
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            for outer in [*node.decorator_list, node.args, *([node.returns] if node.returns else [])]:
                visit(outer)
            return  # its body runs per call: a cache made there is the caller's
        if isinstance(node, ast.Lambda):
            visit(node.args)
            return
        if is_cache(node):
            found.append(f"line {node.lineno}: {ast.unparse(node)}")
            return
        for child in ast.iter_child_nodes(node):
            visit(child)

    visit(tree)
    return found


# ---- the files ------------------------------------------------------------------------------------------------


def _module_name(path: pathlib.Path) -> tuple[str, bool]:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    is_package = parts[-1] == "__init__"
    return ".".join(parts[:-1] if is_package else parts), is_package


def _files(*folders: str) -> Iterator[pathlib.Path]:
    for folder in folders:
        yield from sorted((ROOT / folder).rglob("*.py"))


def _id(path: pathlib.Path) -> str:
    return str(path.relative_to(ROOT))


def test_the_folders_to_check_are_there():
    # a check over no files would pass whatever the code does
    for folder in ["torchfluidwarp", *CLIENTS, *(f"torchfluidwarp/{sub}" for sub in NO_CACHES)]:
        assert any((ROOT / folder).rglob("*.py")), f"no Python files under {folder}"


@pytest.mark.parametrize("path", list(_files("torchfluidwarp", *CLIENTS)), ids=_id)
def test_no_module_imports_a_private_name_from_another_subpackage(path: pathlib.Path):
    module, is_package = _module_name(path)
    found = private_imports(path.read_text(encoding="utf-8"), module, is_package=is_package)
    assert not found, f"{_id(path)} imports private names from outside its own subpackage: {found}"


@pytest.mark.parametrize("path", list(_files("torchfluidwarp")), ids=_id)
def test_no_import_star_in_the_package(path: pathlib.Path):
    assert not star_imports(path.read_text(encoding="utf-8")), _id(path)


def test_no_compatibility_module():
    assert not [p for p in PACKAGE.rglob("_compat*")], "a compatibility layer is back"
    with pytest.raises(ModuleNotFoundError):
        importlib.import_module("torchfluidwarp._compat")


@pytest.mark.parametrize("path", list(_files(*(f"torchfluidwarp/{sub}" for sub in NO_CACHES))), ids=_id)
def test_no_process_wide_cache_in_the_core_and_the_warp(path: pathlib.Path):
    found = process_caches(path.read_text(encoding="utf-8"))
    assert not found, f"{_id(path)} caches for the life of the process: {found}"


@pytest.mark.parametrize("old", FLAT_LAYOUT)
def test_the_flat_layout_stand_ins_are_gone(old: str):
    importlib.import_module("torchfluidwarp")  # the package itself imports, and installs nothing
    with pytest.raises(ModuleNotFoundError):
        importlib.import_module(old)


# ---- the checkers catch what they are for ----------------------------------------------------------------------


@pytest.mark.parametrize(
    "module,source,want",
    [
        # another subpackage's private name, module or attribute
        ("torchfluidwarp.control.newton", "from torchfluidwarp.core.advection import _extend, advect", ["_extend"]),
        ("torchfluidwarp.augment.draw", "from torchfluidwarp.warp.maps import _raster as r", ["maps._raster"]),
        ("torchfluidwarp.morph.fit", "from torchfluidwarp.io._files import atomic", ["io._files"]),
        ("torchfluidwarp.morph.fit", "import torchfluidwarp.io._files as files", ["io._files"]),
        ("torchfluidwarp.morph.fit", "from torchfluidwarp.warp import maps\nmaps._raster(1)", ["line 2: "]),
        ("torchfluidwarp.morph.fit", "import torchfluidwarp\ntorchfluidwarp.core.advection._geo(1)", ["._geo"]),
        ("torchfluidwarp.morph.fit", "from torchfluidwarp.core.graphs import _GraphedStep", ["_GraphedStep"]),
        ("torchfluidwarp.control.newton", "from ..core.advection import _geo", ["core.advection._geo"]),
        ("torchfluidwarp", "from torchfluidwarp.core.fluid import _split", ["_split"]),
        ("torchfluidwarp.control.newton", "from torchfluidwarp._checks import _argument", ["_checks._argument"]),
        ("torchfluidwarp.core.fluid", "from torchfluidwarp.errors import _Explained", ["errors._Explained"]),
        # benchmarks and examples: not even the shared internals
        ("benchmarks.bench_fluid", "from torchfluidwarp._checks import check_tensor", ["torchfluidwarp._checks"]),
        ("examples.plot_x", "from torchfluidwarp.core.grid import _affine", ["_affine"]),
        # allowed: public names, privates of one's own subpackage, the shared internals, dunders, others' privates
        ("torchfluidwarp.control.newton", "from torchfluidwarp.core.staggered import StaggeredGrid", []),
        ("torchfluidwarp.control.keyframes", "from torchfluidwarp.control.optim import _LBFGS", []),
        ("torchfluidwarp.io.images", "from ._files import atomic\nfrom . import _files", []),
        ("torchfluidwarp.core", "from torchfluidwarp.core import graphs\ngraphs._GraphedStep", []),
        (
            "torchfluidwarp.morph.fit",
            "from torchfluidwarp._checks import check_tensor\nimport torchfluidwarp._checks",
            [],
        ),
        ("torchfluidwarp", "from torchfluidwarp._version import __version__", []),
        ("torchfluidwarp.morph.fit", "from torchfluidwarp.core.grid import FluidGrid\nFluidGrid.__name__", []),
        ("benchmarks.bench_fluid", "from _common import _timer\nimport torchfluidwarp as t\nt.FluidWarp", []),
        ("benchmarks.bench_fluid", "from torch.nn import _reduction\nx._private", []),
    ],
)
def test_the_private_import_check_catches_a_violation(module: str, source: str, want: list[str]):
    found = private_imports(source, module)  # each a module, not a package (for those: the test below)
    assert len(found) == len(want), found
    for got, part in zip(found, want):
        assert part in got, (got, part)


def test_a_name_from_a_relative_import_in_a_package_resolves_against_the_package():
    # torchfluidwarp/warp/__init__.py: "from . import _x" is warp's own, "from .. import _x" the top level's
    assert private_imports("from . import _x", "torchfluidwarp.warp", is_package=True) == []
    assert private_imports("from .. import _x", "torchfluidwarp.warp", is_package=True) == ["line 1: torchfluidwarp._x"]
    assert private_imports("from . import _x", "torchfluidwarp.warp.maps") == []


def test_the_star_import_check_catches_a_violation():
    assert star_imports("from torchfluidwarp.warp.maps import *\nimport os") == [
        "line 1: from torchfluidwarp.warp.maps import *"
    ]
    assert star_imports("from .maps import *") == ["line 1: from .maps import *"]
    assert star_imports("from torchfluidwarp.warp.maps import backward_maps") == []


@pytest.mark.parametrize(
    "source,want",
    [
        ("import functools\n@functools.lru_cache(maxsize=32)\ndef f(h): pass", 1),
        ("import functools\n@functools.cache\ndef f(h): pass", 1),
        ("from functools import lru_cache\n@lru_cache\ndef f(h): pass", 1),
        ("from functools import cache as memo\nclass A:\n    @memo\n    def f(self): pass", 1),
        ("import functools as ft\nf = ft.lru_cache()(len)", 1),
        ("import functools\ndef f():\n    @functools.cache\n    def g(): pass\n    return g", 0),  # per call
        ("import functools\n@functools.wraps(len)\ndef f(): pass\nclass A:\n    @functools.cached_property\n"
         "    def x(self): pass", 0),
        ("def cache(f): return f\n@cache\ndef f(): pass", 0),  # not functools'
    ],
)  # fmt: skip
def test_the_cache_check_catches_a_violation(source: str, want: int):
    assert len(process_caches(source)) == want, process_caches(source)
