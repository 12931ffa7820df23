"""A file without a face, as A or as B of a face morph (#31 item 1): the command line and the library refuse it with
a message that names that file and its size, not the other one. No network: the pictures are a seeded noise image
written to ``tmp_path``, the bundled cat and the bundled astronaut (the face)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
import torch
import torch.nn.functional as F

pytest.importorskip("mediapipe", reason="the faces extra (mediapipe) is not installed")

from torchfluidwarp.apps.cli import main  # noqa: E402
from torchfluidwarp.correspond import NoFaceFound, auto_points, find_points  # noqa: E402
from torchfluidwarp.data import load_sample  # noqa: E402
from torchfluidwarp.io import read_image, write_image  # noqa: E402

pytestmark = pytest.mark.usefixtures("one_thread")

FAST = ["--grid", "12", "--steps", "3", "--max-iter", "5", "--frames", "2", "--quiet"]


@pytest.fixture
def files(tmp_path: Path) -> dict[str, Path]:
    """``face.png`` (the astronaut, 256 px), ``noise.png`` (96 x 128 uniform noise) and ``cat.png`` (bundled)."""
    gen = torch.Generator().manual_seed(31)
    pictures = {
        "face": F.interpolate(load_sample("astronaut"), size=(256, 256), mode="bilinear", antialias=True)[0],
        "noise": torch.rand(3, 96, 128, generator=gen),
        "cat": load_sample("cat")[0],
    }
    paths = {name: tmp_path / f"{name}.png" for name in pictures}
    for name, picture in pictures.items():
        write_image(paths[name], picture)
    return paths


def no_face(path: Path) -> str:
    """The refusal's words for ``path``, with its size (W x H)."""
    H, W = read_image(path).shape[-2:]
    return f"no face found in {path} ({W} x {H} pixels)"


@pytest.mark.parametrize("empty", ["noise", "cat"])
@pytest.mark.parametrize("position", ["A", "B"])
def test_the_command_line_names_the_file_without_a_face(files, empty, position, tmp_path, capsys):
    a, b = (files[empty], files["face"]) if position == "A" else (files["face"], files[empty])
    out = tmp_path / "out.gif"
    assert main(["morph", str(a), str(b), "-o", str(out), "--match", "faces", *FAST]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err  # one line: the user's input, not a library bug
    assert no_face(files[empty]) in err
    assert str(files["face"]) not in err
    assert "--match features" in err and "match='" not in err  # the way out, in the command line's words
    assert not out.exists()


@pytest.mark.parametrize("empty", ["noise", "cat"])
@pytest.mark.parametrize("position", ["A", "B"])
def test_the_library_names_the_picture_without_a_face(files, empty, position):
    a, b = (files[empty], files["face"]) if position == "A" else (files["face"], files[empty])
    names = (str(a), str(b))
    pictures = read_image(a), read_image(b)
    with pytest.raises(NoFaceFound, match="^" + re.escape(no_face(files[empty]))) as caught:
        find_points(*pictures, match="faces", names=names)
    assert str(files["face"]) not in str(caught.value)
    assert isinstance(caught.value, ValueError) and caught.value.argument == "image"
    with pytest.raises(NoFaceFound, match="^" + re.escape(no_face(files[empty]))):
        auto_points(*pictures, match="faces", names=names)
