"""The applications call the library and hold no numerics of their own (an AST check over ``apps/``).

No module under ``torchfluidwarp/apps`` may import torch's numerical namespaces (``torch.nn.functional``,
``torch.fft``, ``torch.linalg``, ...) or call the operators that warping, resizing and differencing are made of
(``grid_sample``, ``interpolate``, ``conv2d``, ``gradient``, ...): those live in the library, once. Nor may it
write a pixel-centre rescale ``(x + 0.5) * s - 0.5`` by hand: that is :func:`torchfluidwarp.core.grid.rescale_points`.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

import torchfluidwarp.apps

APPS = Path(torchfluidwarp.apps.__file__).parent
MODULES = sorted(APPS.rglob("*.py"))

NUMERIC_MODULES = ("torch.nn", "torch.fft", "torch.linalg", "torch.special", "kornia", "scipy")
NUMERIC_CALLS = {
    "grid_sample",
    "affine_grid",
    "interpolate",
    "conv2d",
    "conv_transpose2d",
    "avg_pool2d",
    "max_pool2d",
    "pad",
    "gradient",
    "diff",
    "meshgrid",
    "fft",
    "rfft",
    "dct",
    "solve",
    "lstsq",
    "lbfgs",
    "LBFGS",
    "cumsum",
    "einsum",
}


def _imports(tree: ast.AST) -> list[str]:
    names = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names += [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module:
            names += [node.module] + [f"{node.module}.{a.name}" for a in node.names]
    return names


def _called(node: ast.Call) -> str | None:
    f = node.func
    return f.attr if isinstance(f, ast.Attribute) else f.id if isinstance(f, ast.Name) else None


def _is_half(node: ast.AST) -> bool:
    return isinstance(node, ast.Constant) and node.value == 0.5


def _hand_rescale(node: ast.AST) -> bool:
    """``(x + 0.5) * s`` or ``(x + 0.5) / s``: the pixel-centre convention, written again."""
    return (
        isinstance(node, ast.BinOp)
        and isinstance(node.op, (ast.Mult, ast.Div))
        and isinstance(node.left, ast.BinOp)
        and isinstance(node.left.op, ast.Add)
        and (_is_half(node.left.right) or _is_half(node.left.left))
    )


def test_there_are_modules_to_check():
    names = {p.relative_to(APPS).as_posix() for p in MODULES}
    assert {"cli.py", "animate/pipeline.py", "studio/routes.py", "studio/previews.py"} <= names


@pytest.mark.parametrize("path", MODULES, ids=lambda p: p.relative_to(APPS).as_posix())
def test_module_holds_no_numerics(path: Path):
    tree = ast.parse(path.read_text(encoding="utf-8"))
    bad_imports = [n for n in _imports(tree) if n.startswith(NUMERIC_MODULES)]
    assert not bad_imports, f"{path.name} imports numerics: {bad_imports}"
    calls = sorted({name for node in ast.walk(tree) if isinstance(node, ast.Call) and (name := _called(node))})
    assert not NUMERIC_CALLS & set(calls), f"{path.name} calls {sorted(NUMERIC_CALLS & set(calls))}"
    rescales = [node.lineno for node in ast.walk(tree) if _hand_rescale(node)]
    assert not rescales, f"{path.name} rescales pixel positions by hand at lines {rescales}: use core.grid"


def test_the_check_catches_what_it_looks_for():
    tree = ast.parse("import torch.nn.functional as F\ny = F.interpolate(x, size=(2, 2))\nz = (p + 0.5) * s - 0.5\n")
    assert [n for n in _imports(tree) if n.startswith(NUMERIC_MODULES)] == ["torch.nn.functional"]
    assert "interpolate" in {_called(n) for n in ast.walk(tree) if isinstance(n, ast.Call)}
    assert any(_hand_rescale(n) for n in ast.walk(tree))
