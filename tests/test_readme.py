"""The README's Python examples run as written (a new user copies them first), in a temporary folder."""

from __future__ import annotations

import re
import warnings
from pathlib import Path

import pytest
import torch

README = Path(__file__).resolve().parents[1] / "README.md"
BLOCKS = re.findall(r"```python\n(.*?)```", README.read_text(encoding="utf-8"), flags=re.DOTALL)


def test_the_readme_has_its_python_examples():
    assert len(BLOCKS) >= 3  # the morph, the fluid core, the augmentation


@pytest.mark.parametrize("index", range(len(BLOCKS)), ids=lambda i: BLOCKS[i].splitlines()[-1][:40])
def test_a_readme_example_runs_as_written(index, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # result.save("morph.gif") writes here, not into the checkout
    scope: dict[str, object] = {}
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        exec(compile(BLOCKS[index], f"README.md python block {index}", "exec"), scope)  # noqa: S102
        if "paper" in scope:
            assert scope["paper"].folded > 0  # type: ignore[attr-defined]  # renders its frames: it folds here
    said = [str(w.message) for w in caught]
    if "paper" in scope:  # the paper's fit says that it met its marks loosely, as the README's comment does
        assert any("the paper's fit trades them for a smooth flow" in text for text in said), said
        # where it folds, the advice names the paper's own setting (the natural method's would be refused)
        folds = [text for text in said if "maps fold" in text]
        assert folds and all(text.endswith("raising PaperSettings.smoothness smooths the flow") for text in folds)
    if "result" in scope:  # the morph: what the comments say it gives
        result = scope["result"]
        assert tuple(result.frames.shape) == (30, 3, 512, 512) and result.maps.shape == (30, 512, 512, 2)
        assert float(result.error.mean()) < 1 and result.folded == 0  # the default morph meets its marks
        assert (tmp_path / "morph.gif").stat().st_size > 0
    if "sample" in scope:  # the augmentation: every entry of the sample moved by one flow, the label kept
        sample = scope["sample"]
        assert sample["image"].dtype == torch.float32 and sample["label"] == 3
        assert sample["boxes"].shape == (1, 4) and sample["keypoints"].shape == (1, 2)
