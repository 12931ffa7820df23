"""Shared test helpers (seeded generators, a float64 gradcheck) and the skip policy of CI.

With ``TORCHFLUIDWARP_FAIL_ON_SKIP=1`` in the environment (``.ci/run`` sets it) a skipped test fails the run,
unless its reason names hardware that this machine lacks (CUDA, a GPU): the test dependencies are all in the
``[test]`` extra, so any other skip means that something users rely on went untested. The skips are listed
at the end of every run either way.
"""

from __future__ import annotations

import os
import re

import pytest
import torch

FAIL_ON_SKIP = "TORCHFLUIDWARP_FAIL_ON_SKIP"
HARDWARE = re.compile(r"\b(cuda|gpus?|mps)\b", re.IGNORECASE)
"""A skip whose reason matches this names missing hardware, the only kind of skip CI allows."""

_skips: list[tuple[str, str]] = []  # (test or module id, reason), in the order they happened


@pytest.fixture
def gen() -> torch.Generator:
    return torch.Generator().manual_seed(1234)


@pytest.fixture
def one_thread():
    """One torch thread for the test: on a small shared machine, multi-threaded CPU kernels stall whenever
    another process holds a core. Modules opt in with ``pytestmark = pytest.mark.usefixtures("one_thread")``."""
    n = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(n)


@pytest.fixture
def rendered(monkeypatch: pytest.MonkeyPatch) -> list[int]:
    """The number of frames of each call to the morph's renderer (``morph.result.render``), as the test runs
    (tests/apps: a report's pass renders each frame once)."""
    from torchfluidwarp.morph import result as morph_result

    calls: list[int] = []
    render = morph_result.render

    def counted(scene, ts, *args, **kwargs):
        calls.append(len(ts))
        return render(scene, ts, *args, **kwargs)

    monkeypatch.setattr(morph_result, "render", counted)
    return calls


@pytest.fixture
def shuffled_marks() -> tuple[torch.Tensor, torch.Tensor]:
    """12 marks ``(12, 2)`` float64 pixels in a 64 x 64 picture, and the same marks in a shuffled order: a
    similarity explains 7% of the shuffled set's spread, an affine 12% (no common pose; tests/morph)."""
    pa = torch.tensor(
        [
            [8, 21],
            [46, 15],
            [45, 38],
            [16, 29],
            [27, 46],
            [16, 37],
            [29, 24],
            [56, 11],
            [12, 34],
            [55, 13],
            [40, 34],
            [9, 20],
        ],
        dtype=torch.float64,
    )
    return pa, pa[torch.tensor([7, 3, 10, 0, 11, 5, 1, 9, 2, 6, 4, 8])]


def gradcheck64(fn, *inputs: torch.Tensor, **kwargs) -> bool:
    """``torch.autograd.gradcheck`` on float64 copies of ``inputs`` (all made to require grad)."""
    xs = [x.detach().to(torch.float64).requires_grad_() for x in inputs]
    return torch.autograd.gradcheck(fn, xs, eps=1e-6, atol=1e-6, rtol=1e-5, **kwargs)


def _record_skip(report: pytest.CollectReport | pytest.TestReport) -> None:
    if not report.skipped or hasattr(report, "wasxfail"):  # an expected failure is not a skip
        return
    longrepr = report.longrepr
    reason = longrepr[2] if isinstance(longrepr, tuple) else str(longrepr)
    _skips.append((report.nodeid, reason.removeprefix("Skipped: ")))


def pytest_collectreport(report: pytest.CollectReport) -> None:
    _record_skip(report)  # a module that skips itself (pytest.skip(..., allow_module_level=True))


def pytest_runtest_logreport(report: pytest.TestReport) -> None:
    _record_skip(report)


def _disallowed() -> list[tuple[str, str]]:
    return [(node, reason) for node, reason in _skips if not HARDWARE.search(reason)]


def pytest_sessionfinish(session: pytest.Session, exitstatus: int) -> None:
    if os.environ.get(FAIL_ON_SKIP) == "1" and _disallowed() and exitstatus == pytest.ExitCode.OK:
        session.exitstatus = pytest.ExitCode.TESTS_FAILED


def pytest_terminal_summary(terminalreporter, exitstatus: int, config: pytest.Config) -> None:
    if not _skips:
        return
    strict = os.environ.get(FAIL_ON_SKIP) == "1"
    terminalreporter.section("skips")
    for node, reason in _skips:
        verdict = "allowed: needs hardware" if HARDWARE.search(reason) else "NOT ALLOWED" if strict else "skipped"
        terminalreporter.line(f"{verdict}: {node}: {reason}")
    bad = _disallowed()
    if strict and bad:
        terminalreporter.line(
            f"{len(bad)} skip(s) without a hardware reason: {FAIL_ON_SKIP}=1 makes them fail the run "
            "(install the [test] extra; the browser tests need /usr/bin/chromium)",
            red=True,
        )
