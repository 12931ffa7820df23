"""Fixtures shared by the command-line tests."""

from __future__ import annotations

import pytest


@pytest.fixture
def rendered(monkeypatch: pytest.MonkeyPatch) -> list[int]:
    """The number of frames of each call to the morph's renderer (``morph.result.render``), as the test runs."""
    from torchfluidwarp.morph import result as morph_result

    calls: list[int] = []
    render = morph_result.render

    def counted(scene, ts, *args, **kwargs):
        calls.append(len(ts))
        return render(scene, ts, *args, **kwargs)

    monkeypatch.setattr(morph_result, "render", counted)
    return calls
