"""Tests for the ``torchfluidwarp`` command line (run in-process through ``main``) and its config parser."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import imageio.v3 as iio
import numpy as np
import pytest
import torch
import torch.nn.functional as F

from torchfluidwarp.apps.animate import brush_from_values, build_viscosity, load_config, parse_config
from torchfluidwarp.apps.cli import main
from torchfluidwarp.data import load_sample
from torchfluidwarp.io import write_image

STEPS = 6
BRUSH = "24,24,1,0.5,8,0.1,0.8"
FAST = ["--grid", "16", "--steps", str(STEPS), "--quiet"]


@pytest.fixture
def image(tmp_path: Path, gen: torch.Generator) -> Path:
    """A 48 x 48 RGB test photo: smooth stripes plus noise, so a warp changes its pixels."""
    ys, xs = torch.meshgrid(torch.arange(48.0), torch.arange(48.0), indexing="ij")
    stripes = torch.stack([torch.sin(xs / 3), torch.cos(ys / 4), torch.sin((xs + ys) / 5)]) * 0.4 + 0.5
    img = (stripes + 0.05 * torch.rand(3, 48, 48, generator=gen)).clamp(0, 1)
    return write_image(tmp_path / "photo.png", img)


def animate(image: Path, out: Path | str, *extra: str) -> int:
    return main(["animate", str(image), "-o", str(out), "--brush", BRUSH, *FAST, *extra])


def one_line_error(capsys: pytest.CaptureFixture, *words: str) -> str:
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err, err
    for w in words:
        assert w in err, err
    return err


def test_gif_has_steps_plus_one_frames(tmp_path, image, capsys):
    out = tmp_path / "anim.gif"
    assert animate(image, out, "--fps", "10") == 0
    frames = iio.imread(out, index=None)
    assert frames.shape == (STEPS + 1, 48, 48, 3)
    assert not (frames[-1] == frames[0]).all()  # the brush moved something
    assert capsys.readouterr().out.strip() == str(out)


def test_refuses_to_overwrite_then_overwrites(tmp_path, image, capsys):
    out = tmp_path / "anim.gif"
    out.write_bytes(b"keep me")
    assert animate(image, out) == 2
    one_line_error(capsys, "already exists", "--overwrite")
    assert out.read_bytes() == b"keep me"
    assert animate(image, out, "--overwrite") == 0
    assert iio.imread(out, index=None).shape[0] == STEPS + 1


def test_frames_folder(tmp_path, image):
    out = tmp_path / "frames"
    assert animate(image, f"{out}/") == 0
    assert sorted(p.name for p in out.iterdir()) == [f"frame_{t:04d}.png" for t in range(STEPS + 1)]


def test_missing_image(tmp_path, capsys):
    assert animate(tmp_path / "nope.png", tmp_path / "a.gif") == 2
    one_line_error(capsys, "nope.png")
    assert not (tmp_path / "a.gif").exists()


@pytest.mark.parametrize(
    ("text", "words"),
    [
        ('{"steps": 4,}', ["not valid JSON", "line 1"]),
        ('{"stpes": 4}', ["unknown key 'stpes'"]),
        (
            '{"brushes": [{"position": [1, 2], "direction": [0, 1], "radius": 3, "amplitude": 1, "freq": 1}]}',
            ["brushes[0]", "unknown key 'freq'"],
        ),
        (
            '{"brushes": [{"position": [1, 2], "direction": [0, 1], "radius": -3, "amplitude": 1}]}',
            ["brushes[0].radius", "-3"],
        ),
        ('{"viscosity": {"regions": [{"position": [1], "radius": 3, "value": 1}]}}', ["viscosity.regions[0].position"]),
        ('{"steps": 2.5}', ["steps", "2.5"]),
        ('{"grid": [16]}', ["grid"]),
        ("[" * 100_000 + "]" * 100_000, ["nested too deeply"]),  # the JSON decoder recursed past the stack
    ],
)
def test_bad_config_exits_2(tmp_path, image, capsys, text, words):
    config = tmp_path / "forces.json"
    config.write_text(text)
    assert main(["animate", str(image), "-o", str(tmp_path / "a.gif"), "--config", str(config), "--quiet"]) == 2
    one_line_error(capsys, "forces.json", *words)
    assert not (tmp_path / "a.gif").exists()


@pytest.mark.parametrize("brush", ["1,2,3", "24,24,1,0,8,0.1,0.8,0,9", "24,24,1,0,8,0.1,abc", "24,24,0,0,8,0.1,1"])
def test_bad_brush_exits_2(tmp_path, image, capsys, brush):
    assert main(["animate", str(image), "-o", str(tmp_path / "a.gif"), "--brush", brush]) == 2
    one_line_error(capsys, "--brush")


@pytest.mark.parametrize(
    "options",
    [["--steps", "0"], ["--fps", "-1"], ["--grid", "8", "8", "8"], ["--max-size", "x"], ["--viscosity", "-0.5"]],
)
def test_bad_options_exit_2(tmp_path, image, capsys, options):
    assert main(["animate", str(image), "-o", str(tmp_path / "a.gif"), "--brush", BRUSH, *options]) == 2
    one_line_error(capsys)


def test_no_brush_and_bad_suffix_exit_2(tmp_path, image, capsys):
    assert main(["animate", str(image), "-o", str(tmp_path / "a.gif")]) == 2
    one_line_error(capsys, "--brush")
    assert animate(image, tmp_path / "a.webm") == 2
    one_line_error(capsys, ".webm")


def test_mp4_without_ffmpeg_exits_2_before_rendering(tmp_path, image, capsys, monkeypatch):
    import importlib.util

    find_spec = importlib.util.find_spec
    monkeypatch.setattr(
        importlib.util, "find_spec", lambda name, *a: None if name == "imageio_ffmpeg" else find_spec(name, *a)
    )
    assert animate(image, tmp_path / "a.mp4") == 2
    one_line_error(capsys, "imageio-ffmpeg")
    assert list(tmp_path.iterdir()) == [image]


def test_mp4_through_the_cli_stays_close_to_the_gif(tmp_path):
    import imageio_ffmpeg  # noqa: F401  (the [video] extra, which [test] pulls in)

    # The bundled cat at 64 x 48, not the noisy stripes: H.264 and the GIF palette both smooth away noise.
    photo = write_image(tmp_path / "cat.png", F.interpolate(load_sample("cat"), size=(48, 64), mode="area"))
    push = ["--brush", "32,24,1,0.5,10,0.1,2.0", *FAST]
    assert main(["animate", str(photo), "-o", str(tmp_path / "a.gif"), *push]) == 0
    assert main(["animate", str(photo), "-o", str(tmp_path / "a.mp4"), *push]) == 0
    gif = iio.imread(tmp_path / "a.gif", index=None).astype(np.float64)  # (T, H, W, 3) in 0..255
    mp4 = iio.imread(tmp_path / "a.mp4", plugin="FFMPEG").astype(np.float64)
    assert gif.shape == mp4.shape == (STEPS + 1, 48, 64, 3)
    # Codec loss (H.264 at this size, the GIF's 256 colours) measured 4.6 to 5.6 levels per frame; the brush
    # moves the picture by about 19 levels between the first and the last frame.
    tol = 8.0
    assert np.abs(mp4 - gif).mean(axis=(1, 2, 3)).max() < tol
    assert np.abs(gif[-1] - gif[0]).mean() > 2 * tol  # the check means something: the frames differ
    assert np.abs(mp4[-1] - gif[-1]).mean() < np.abs(mp4[-1] - gif[0]).mean()  # in order, not reversed


def test_config_file_and_command_line_override(tmp_path, image):
    mask = torch.zeros(1, 48, 48)
    mask[:, :, :16] = 1.0
    write_image(tmp_path / "stiff.png", mask)
    config = tmp_path / "forces.json"
    config.write_text(
        json.dumps(
            {
                "brushes": [
                    {"position": [24, 24], "direction": [0, 1], "radius": 8, "frequency": 0.1, "amplitude": 0.8}
                ],
                "viscosity": {
                    "base": 0.1,
                    "regions": [{"position": [40, 8], "radius": 5, "value": 2}],
                    "mask": "stiff.png",
                },
                "grid": [12, 16],
                "steps": 3,
                "fps": 5,
            }
        )
    )
    out = tmp_path / "anim.gif"
    assert main(["animate", str(image), "-o", str(out), "--config", str(config), "--steps", "4", "--quiet"]) == 0
    assert iio.imread(out, index=None).shape[0] == 5  # --steps beat the file's 3

    cfg = load_config(config)
    assert cfg.grid == (12, 16) and cfg.viscosity.mask == tmp_path / "stiff.png"
    field = build_viscosity(cfg, (12, 16), (48, 48))
    assert field.shape == (1, 1, 12, 16)
    assert field[0, 0, :, 0].min() > 5.0 and field[0, 0, 6, 8] < 0.2  # stiff left band, soft centre


def test_max_size_downscales_and_keeps_brushes_in_place(tmp_path, image, capsys):
    out = tmp_path / "small"
    loud = [option for option in FAST if option != "--quiet"]
    assert main(["animate", str(image), "-o", str(out), "--brush", BRUSH, *loud, "--max-size", "24"]) == 0
    assert iio.imread(out / "frame_0000.png").shape == (24, 24, 3)
    err = capsys.readouterr().err  # the shrinking is said, as morph says it, and the run's size and time
    assert "frames written at 24 x 24 px: the photo's 48 x 48 shrunk to --max-size 24" in err
    assert re.search(r"animate: \d+ frames of 24 x 24 px, [\d.]+ s \(", err)
    assert main(["animate", str(image), "-o", str(tmp_path / "whole"), "--brush", BRUSH, *loud]) == 0
    assert "shrunk" not in capsys.readouterr().err  # 48 px is within the default 800
    spec = parse_config({"brushes": [{"position": [23.5, 47.5], "direction": [1, 0], "radius": 8, "amplitude": 2}]})
    b = spec.rescaled(0.5, 0.5).brushes[0]
    assert b.position == (11.5, 23.5) and b.radius == 4 and b.amplitude == 1


def test_brush_values_match_json():
    assert (
        brush_from_values([1, 2, 0, 1, 5, 0.1, 0.5])
        == parse_config(
            {"brushes": [{"position": [1, 2], "direction": [0, 1], "radius": 5, "frequency": 0.1, "amplitude": 0.5}]}
        ).brushes[0]
    )


@pytest.mark.parametrize("command", ["animate", "demo", "morph", "studio"])
def test_subcommands_are_registered(command, capsys):
    # Only their --help: demo, morph and studio belong to other modules (studio starts a server).
    assert main([command, "--help"]) == 0
    assert f"torchfluidwarp {command}" in capsys.readouterr().out


def test_help_exits_0(capsys):
    assert main(["animate", "--help"]) == 0
    assert '"brushes"' in capsys.readouterr().out


def test_console_entry_point():
    # `python -m torchfluidwarp`, as a user tries first, runs the same command line as the script
    done = subprocess.run(
        [sys.executable, "-m", "torchfluidwarp", "--help"], capture_output=True, text=True, timeout=120
    )
    assert done.returncode == 0, done.stderr
    assert "animate" in done.stdout and "morph" in done.stdout


def test_a_flow_too_strong_is_refused_in_the_command_lines_terms(tmp_path, image, capsys):
    # the library's error suggests MapConfig(max_substeps=...), which the command line has no flag for
    rc = main(
        ["animate", str(image), "-o", str(tmp_path / "o.gif"), "--brush", "32,32,1,0,10,0,100000", "--steps", "3"]
    )
    err = capsys.readouterr().err
    assert rc == 3 and "sub-steps" in err and "reduce the forces" in err  # exit 3: the flow blew up
    assert "MapConfig" not in err and "max_substeps" not in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "o.gif").exists()
