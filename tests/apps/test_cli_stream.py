"""The command line streams frames to its writers, and refuses what cannot fit before any work."""

from __future__ import annotations

import shutil
import subprocess
import sys
from collections import namedtuple
from pathlib import Path

import imageio.v3 as iio
import numpy as np
import pytest
import torch

from torchfluidwarp.apps.cli import main
from torchfluidwarp.apps.cli_args import output_bytes
from torchfluidwarp.core.grid import SquareCells
from torchfluidwarp.io import read_image, read_points, write_animation, write_image, write_points
from torchfluidwarp.morph import NaturalSettings, morph

FAST = ["--grid", "12", "--steps", "2", "--max-iter", "5", "--quiet"]
POINTS_A = torch.tensor([[8.0, 8.0], [24.0, 9.0], [15.0, 22.0]])


@pytest.fixture
def pair(tmp_path, gen):
    data = tmp_path / "data"
    data.mkdir()
    write_image(data / "a.png", torch.rand(3, 32, 36, generator=gen))
    write_image(data / "b.png", torch.rand(3, 40, 30, generator=gen))
    write_points(data / "a.pts", POINTS_A)
    write_points(data / "b.pts", POINTS_A + torch.tensor([2.0, 3.0]))
    return (
        [str(data / n) for n in ("a.png", "b.png")]
        + ["--points-a", str(data / "a.pts")]
        + [
            "--points-b",
            str(data / "b.pts"),
        ]
    )


def listing(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir())


@pytest.mark.parametrize("name", ["m.gif", "frames/"])
def test_streamed_morph_writes_the_materialised_frames(tmp_path, pair, name):
    out = tmp_path / "out" / name
    assert main(["morph", *pair, "-o", str(out), "--frames", "7", *FAST]) == 0
    data = Path(pair[0]).parent
    result = morph(
        read_image(data / "a.png"),
        read_image(data / "b.png"),
        read_points(data / "a.pts"),
        read_points(data / "b.pts"),
        settings=NaturalSettings(grid=SquareCells(12 * 12), steps=2, max_iter=5),  # "--grid 12"
        frames=7,
    )
    whole = write_animation(tmp_path / "whole" / name, result.frames)
    if name.endswith("/"):
        got = np.stack([iio.imread(p) for p in sorted(out.iterdir())])
        want = np.stack([iio.imread(p) for p in sorted(whole.iterdir())])
    else:
        got, want = iio.imread(out, index=None), iio.imread(whole, index=None)
    assert got.shape == want.shape and got.shape[0] == 7
    assert np.abs(got.astype(int) - want.astype(int)).max() <= 1  # float rounding of the same render


def test_animate_streams_its_frames(tmp_path, gen):
    photo = tmp_path / "p.png"
    write_image(photo, torch.rand(3, 24, 28, generator=gen))
    out = tmp_path / "a" / "frames"
    argv = ["animate", str(photo), "-o", f"{out}/", "--brush", "14,12,1,0,6,0.1,0.5", "--steps", "5", "-q"]
    assert main(argv) == 0
    assert listing(out) == [f"frame_{k:04d}.png" for k in range(6)]


def test_no_disk_space_is_refused_before_work(tmp_path, pair, monkeypatch, capsys):
    Usage = namedtuple("Usage", "total used free")
    monkeypatch.setattr(shutil, "disk_usage", lambda path: Usage(10**6, 10**6 - 5000, 5000))
    calls = []
    monkeypatch.setattr("torchfluidwarp.apps.cli_morph.morph", lambda *a, **k: calls.append(1))
    out = tmp_path / "out" / "m.gif"
    assert main(["morph", *pair, "-o", str(out), "--frames", "30", *FAST]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    need = output_bytes(str(out), 30, 32, 36, 3)
    assert f"would need about {need / 1024:.1f} KiB (30 frames of 36x32), above the 4.9 KiB free" in err
    assert calls == [] and not (tmp_path / "out").exists()
    photo = tmp_path / "p.png"
    write_image(photo, torch.rand(3, 24, 28))
    argv = ["animate", str(photo), "-o", str(tmp_path / "anim.gif"), "--brush", "14,12,1,0,6,0.1,0.5", "--steps", "20"]
    assert main(argv) == 2
    assert "frames of 28x24" in capsys.readouterr().err
    assert listing(tmp_path) == ["data", "p.png"]


@pytest.mark.parametrize(
    "option, why",
    [
        (["--frames", "1000000000000"], "would need about .* TiB .* free in"),
        (["--steps", "1000000000"], r"would need about .* TiB, above the limit of 8.0 GiB; .* --max-memory GIB"),
        (["--grid", "200000"], "above the limit of 8.0 GiB"),
        (["--fps", "5000"], "fps must be from 0.01 to 1000"),
        (["--fps", "nan"], "fps must be"),
    ],
)
def test_absurd_requests_exit_2_with_one_line_and_no_output(tmp_path, pair, capsys, option, why):
    out = tmp_path / "out" / "m.gif"
    assert main(["morph", *pair, "-o", str(out), *FAST, *option]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert __import__("re").search(why, err), err
    assert not (tmp_path / "out").exists()


def test_max_memory_lets_a_small_limit_refuse(tmp_path, pair, capsys):
    out = tmp_path / "m.gif"
    assert main(["morph", *pair, "-o", str(out), *FAST, "--max-memory", "0.00001"]) == 2
    assert "above the limit of 10.5 KiB" in capsys.readouterr().err and not out.exists()


PEAK = """
import resource, sys
from torchfluidwarp.apps.cli import main
rc = main(sys.argv[1:])
print(rc, resource.getrusage(resource.RUSAGE_SELF).ru_maxrss)
"""


def test_peak_memory_does_not_grow_with_the_frame_count(tmp_path, gen):
    """A 96x96 morph of 8 and of 300 frames: materialised, the 300 would hold about 230 MB of frames and maps."""
    data = tmp_path / "data"
    data.mkdir()
    write_image(data / "a.png", torch.rand(3, 96, 96, generator=gen))
    write_image(data / "b.png", torch.rand(3, 96, 96, generator=gen))
    points = torch.tensor([[20.0, 20.0], [70.0, 25.0], [45.0, 70.0]])
    write_points(data / "a.pts", points)
    write_points(data / "b.pts", points + 3)
    peaks = {}
    for frames in (8, 300):
        argv = [str(data / "a.png"), str(data / "b.png"), "--points-a", str(data / "a.pts")]
        argv += ["--points-b", str(data / "b.pts"), "-o", str(tmp_path / f"{frames}.gif"), "--frames", str(frames)]
        run = subprocess.run(
            [sys.executable, "-c", PEAK, "morph", *argv, *FAST], capture_output=True, text=True, timeout=300
        )
        rc, kib = run.stdout.split()[-2:]  # after the path the command prints
        assert rc == "0", run.stderr
        peaks[frames] = int(kib) * 1024
    assert len(iio.imread(tmp_path / "300.gif", index=None)) == 300
    assert peaks[300] - peaks[8] < 60e6, peaks
