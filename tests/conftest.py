"""Shared test helpers: seeded generators and a float64 gradcheck."""

from __future__ import annotations

import pytest
import torch


@pytest.fixture
def gen() -> torch.Generator:
    return torch.Generator().manual_seed(1234)


def gradcheck64(fn, *inputs: torch.Tensor, **kwargs) -> bool:
    """``torch.autograd.gradcheck`` on float64 copies of ``inputs`` (all made to require grad)."""
    xs = [x.detach().to(torch.float64).requires_grad_() for x in inputs]
    return torch.autograd.gradcheck(fn, xs, eps=1e-6, atol=1e-6, rtol=1e-5, **kwargs)
