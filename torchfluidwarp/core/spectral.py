"""Fast transforms that diagonalise the grid's constant-coefficient operators.

torch has no DCT or DST, so both are built on ``torch.fft`` in ``O(n log n)`` per axis:

* DCT-II (Makhoul's reordering): diagonalises the cell-centred 1-D Laplacian with zero-flux (Neumann)
  walls, eigenvalues ``4 sin^2(pi k / 2n)``, ``k = 0..n-1``.
* DST-I (odd extension): diagonalises the node-centred 1-D Laplacian whose end nodes are held at zero
  (Dirichlet), ``n`` interior nodes, eigenvalues ``4 sin^2(pi k / 2(n + 1))``, ``k = 1..n``.

On the staggered grid the pressure matrix is DCT x DCT, and each velocity component's diffusion matrix is
DST along its own axis times DCT along the other, so :func:`solve_pressure_poisson` and
:func:`solve_velocity_helmholtz` invert them exactly. They serve as the conjugate-gradient preconditioners.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import torch
from torch import Tensor

__all__ = ["dct", "idct", "dst1", "idst1", "SpectralBases", "solve_pressure_poisson", "solve_velocity_helmholtz"]


def _along(fn, x: Tensor, dim: int) -> Tensor:
    if dim in (-1, x.ndim - 1):
        return fn(x)
    return fn(x.transpose(dim, -1)).transpose(dim, -1)


def _twiddle(n: int, sign: float, x: Tensor) -> Tensor:
    k = torch.arange(n, device=x.device, dtype=x.dtype)
    return torch.polar(torch.ones_like(k), sign * math.pi * k / (2 * n))


def _dct_last(x: Tensor) -> Tensor:
    n = x.shape[-1]
    v = torch.cat([x[..., ::2], x[..., 1::2].flip(-1)], dim=-1)
    return (torch.fft.fft(v) * _twiddle(n, -1.0, x)).real


def _idct_last(X: Tensor) -> Tensor:
    n = X.shape[-1]
    half = n // 2 + 1
    # X_{n-k} for k = 0..n//2, with X_n := 0
    mirrored = torch.cat([torch.zeros_like(X[..., :1]), X[..., 1:].flip(-1)], dim=-1)[..., :half]
    V = torch.complex(X[..., :half], -mirrored) * _twiddle(n, 1.0, X)[:half]
    v = torch.fft.irfft(V, n=n)
    x = torch.empty_like(X)
    even = (n + 1) // 2
    x[..., ::2] = v[..., :even]
    x[..., 1::2] = v[..., even:].flip(-1)
    return x


def _dst1_last(x: Tensor) -> Tensor:
    zero = torch.zeros_like(x[..., :1])
    y = torch.cat([zero, x, zero, -x.flip(-1)], dim=-1)  # odd extension, length 2(n + 1)
    return -0.5 * torch.fft.rfft(y).imag[..., 1 : x.shape[-1] + 1]


def dct(x: Tensor, dim: int = -1) -> Tensor:
    """Unnormalised DCT-II along ``dim``: ``X_k = sum_n x_n cos(pi (2n + 1) k / 2N)``.

    Example:
        >>> x = torch.tensor([1.0, 2.0, 3.0])
        >>> torch.allclose(idct(dct(x)), x)
        True
    """
    return _along(_dct_last, x, dim)


def idct(X: Tensor, dim: int = -1) -> Tensor:
    """Inverse of :func:`dct` along ``dim`` (a scaled DCT-III)."""
    return _along(_idct_last, X, dim)


def dst1(x: Tensor, dim: int = -1) -> Tensor:
    """Unnormalised DST-I along ``dim``: ``X_k = sum_{n=1}^{N} x_n sin(pi n k / (N + 1))``."""
    return _along(_dst1_last, x, dim)


def idst1(X: Tensor, dim: int = -1) -> Tensor:
    """Inverse of :func:`dst1` along ``dim``: the DST-I scaled by ``2 / (N + 1)``."""
    return dst1(X, dim) * (2.0 / (X.shape[dim] + 1))


DENSE_MAX = 256
"""Axes up to this length are transformed with a dense orthonormal matrix (faster than several FFT calls at
these sizes on CPUs); longer axes use the ``O(n log n)`` FFT transforms above."""


class SpectralBases:
    """The transform matrices and eigenvalues of the solves below, built on first use per size, device and dtype
    and held by this instance (a :class:`~torchfluidwarp.core.staggered.StaggeredGrid` holds one, so a simulator
    holds its own). A solve given none builds what it needs anew."""

    def __init__(self) -> None:
        self._memo: dict[tuple, object] = {}

    def _get(self, key: tuple, build: Callable[[], object]) -> object:
        found = self._memo.get(key)
        if found is None:
            with torch.inference_mode(False), torch.no_grad():
                found = self._memo[key] = build()
        return found

    def axis(self, n: int, kind: str, like: Tensor) -> tuple[Tensor | None, Tensor]:
        """``(orthonormal transform matrix or None, eigenvalues)`` for one axis of ``n`` samples."""
        return self._get(("axis", n, kind, like.device, like.dtype), lambda: _axis(n, kind, like.device, like.dtype))  # type: ignore[return-value]

    def eigenvalues(self, ny: int, nx: int, kind_y: str, kind_x: str, like: Tensor) -> Tensor:
        """The ``(ny, nx)`` eigenvalues of ``-L`` for the given axis kinds."""
        key = ("eig", ny, nx, kind_y, kind_x, like.device, like.dtype)
        return self._get(key, lambda: self.axis(ny, kind_y, like)[1][:, None] + self.axis(nx, kind_x, like)[1][None, :])  # type: ignore[return-value]

    def pressure_gain(self, h: int, w: int, like: Tensor) -> Tensor:
        """``1 / e`` per cosine mode of the ``(h, w)`` Neumann Laplacian (1 for ``e = 0``)."""

        def build() -> Tensor:
            eig = self.eigenvalues(h, w, "neumann", "neumann", like)
            return 1.0 / torch.where(eig > 0, eig, 1.0)

        return self._get(("gain", h, w, like.device, like.dtype), build)  # type: ignore[return-value]


def _axis(n: int, kind: str, device: torch.device, dtype: torch.dtype) -> tuple[Tensor | None, Tensor]:
    """``(orthonormal transform matrix or None, eigenvalues)`` for one axis."""
    k = torch.arange(n, device=device, dtype=torch.float64)
    if kind == "neumann":
        eig = 4 * torch.sin(math.pi * k / (2 * n)) ** 2
        mat = torch.cos(math.pi * (2 * k[None, :] + 1) * k[:, None] / (2 * n)) * math.sqrt(2.0 / n)
        mat[0] /= math.sqrt(2.0)
    else:
        eig = 4 * torch.sin(math.pi * (k + 1) / (2 * (n + 1))) ** 2
        mat = torch.sin(math.pi * (k[None, :] + 1) * (k[:, None] + 1) / (n + 1)) * math.sqrt(2.0 / (n + 1))
    return (mat.to(dtype) if n <= DENSE_MAX else None), eig.to(dtype)


def _forward(x: Tensor, kind: str, dim: int, bases: SpectralBases) -> Tensor:
    n = x.shape[dim]
    mat = bases.axis(n, kind, x)[0]
    if mat is not None:
        return x @ mat.T if dim == -1 else mat @ x
    if kind == "neumann":
        return dct(x, dim) * _dct_scale(n, x, dim)
    return dst1(x, dim) * math.sqrt(2.0 / (n + 1))


def _inverse(x: Tensor, kind: str, dim: int, bases: SpectralBases) -> Tensor:
    n = x.shape[dim]
    mat = bases.axis(n, kind, x)[0]
    if mat is not None:
        return x @ mat if dim == -1 else mat.T @ x
    if kind == "neumann":
        return idct(x / _dct_scale(n, x, dim), dim)
    return dst1(x, dim) * math.sqrt(2.0 / (n + 1))


def _dct_scale(n: int, like: Tensor, dim: int) -> Tensor:
    """Scale that makes :func:`dct` orthonormal, shaped to broadcast along ``dim`` (-1 or -2)."""
    s = torch.full((n,), math.sqrt(2.0 / n), device=like.device, dtype=like.dtype)
    s[0] = math.sqrt(1.0 / n)
    return s if dim == -1 else s[:, None]


def solve_pressure_poisson(b: Tensor, bases: SpectralBases | None = None) -> Tensor:
    """Solve ``-L p = b`` for the 5-point Laplacian with zero-flux walls, exactly.

    Args:
        b: ``(B, 1, h, w)`` right-hand side. Its mean (the operator's null space) is ignored.

    Returns:
        ``(B, 1, h, w)`` the solution ``p``. The constant mode (the Laplacian's null space) is given
        eigenvalue 1, i.e. this inverts ``-L p + mean(p)``: a zero-mean ``b`` gets the zero-mean solution.
    """
    h, w = b.shape[-2:]
    bases = SpectralBases() if bases is None else bases
    coef = _forward(_forward(b, "neumann", -1, bases), "neumann", -2, bases) * bases.pressure_gain(h, w, b)
    return _inverse(_inverse(coef, "neumann", -2, bases), "neumann", -1, bases)


def _solve_component(b: Tensor, alpha: Tensor, kind_y: str, kind_x: str, bases: SpectralBases) -> Tensor:
    ny, nx = b.shape[-2:]
    eig = bases.eigenvalues(ny, nx, kind_y, kind_x, b)
    coef = _forward(_forward(b, kind_x, -1, bases), kind_y, -2, bases) / (1 + alpha.reshape(-1, 1, 1) * eig)
    return _inverse(_inverse(coef, kind_y, -2, bases), kind_x, -1, bases)


def solve_velocity_helmholtz(b: Tensor, alpha: Tensor, bases: SpectralBases | None = None) -> Tensor:
    """Solve ``(I - alpha L) v = b`` for a staggered velocity, exactly, component by component.

    ``L`` is the vector Laplacian with no flow through the walls (Dirichlet for the normal component) and
    free slip along them (Neumann for the tangential one).

    Args:
        b: ``(B, 2, h + 1, w + 1)`` staggered right-hand side (see :mod:`torchfluidwarp.core.grid`).
        alpha: ``(B,)`` non-negative ``dt * viscosity`` per batch element (cells^2).

    Returns:
        ``(B, 2, h + 1, w + 1)`` the solution; entries on walls and padding are passed through unchanged (the
        operator is the identity there), so that adjoint right-hand sides with wall entries stay consistent.
    """
    h, w = b.shape[-2] - 1, b.shape[-1] - 1
    bases = SpectralBases() if bases is None else bases
    out = b.clone()
    out[:, 0, :h, 1:w] = _solve_component(b[:, 0, :h, 1:w], alpha, "neumann", "dirichlet", bases)
    out[:, 1, 1:h, :w] = _solve_component(b[:, 1, 1:h, :w], alpha, "dirichlet", "neumann", bases)
    return out


def neumann_filter(b: Tensor, gain: Callable[[Tensor], Tensor], bases: SpectralBases | None = None) -> Tensor:
    """Apply a function of the Neumann Laplacian to a cell-centred field: ``IDCT(gain(e) * DCT(b))``.

    Args:
        b: ``(B, 1, h, w)`` field.
        gain: maps the eigenvalues ``e`` ``(h, w)`` of ``-L`` (``>= 0``) to per-mode gains, broadcastable
            against ``(B, 1, h, w)``.
    """
    h, w = b.shape[-2:]
    bases = SpectralBases() if bases is None else bases
    eig = bases.eigenvalues(h, w, "neumann", "neumann", b)
    coef = _forward(_forward(b, "neumann", -1, bases), "neumann", -2, bases) * gain(eig)
    return _inverse(_inverse(coef, "neumann", -2, bases), "neumann", -1, bases)
