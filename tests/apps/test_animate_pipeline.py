"""The one animate pipeline (``apps.animate``): the command line and the studio make the same frames from it."""

from __future__ import annotations

import io
import json
import warnings
from pathlib import Path

import imageio.v3 as iio
import numpy as np
import pytest
import torch

with warnings.catch_warnings():  # newer Starlette suggests httpx2 for its TestClient; httpx still works
    warnings.simplefilter("ignore")
    from starlette.testclient import TestClient

from torchfluidwarp.apps.animate import AnimationConfig, animate_frames, build_viscosity, config_json, parse_config
from torchfluidwarp.apps.cli import main
from torchfluidwarp.apps.studio import StudioConfig, create_app
from torchfluidwarp.core.grid import rescale_points, scale_factor
from torchfluidwarp.io import read_image, write_image
from torchfluidwarp.warp.forces import Brushes
from torchfluidwarp.warp.layer import FluidWarp

CONFIG = {
    "brushes": [
        {"position": [30, 20], "direction": [0, -1], "radius": 8, "frequency": 0.1, "amplitude": 1.5},
        {"position": [12, 34], "direction": [1, 1], "radius": 6, "frequency": 0.0, "amplitude": 0.4, "phase": 1.0},
    ],
    "viscosity": {"base": 0.1, "regions": [{"position": [10, 10], "radius": 5, "value": 4}]},
    "grid": [12, 16],
    "steps": 5,
    "fps": 12,
}


@pytest.fixture
def photo(tmp_path: Path, gen: torch.Generator) -> Path:
    """A 40 x 56 RGB picture: smooth stripes plus noise, so the warp changes its pixels."""
    ys, xs = torch.meshgrid(torch.arange(40.0), torch.arange(56.0), indexing="ij")
    stripes = torch.stack([torch.sin(xs / 3), torch.cos(ys / 4), torch.sin((xs + ys) / 5)]) * 0.4 + 0.5
    return write_image(tmp_path / "photo.png", (stripes + 0.05 * torch.rand(3, 40, 56, generator=gen)).clamp(0, 1))


def studio_frames(photo: Path, config: dict, **settings) -> tuple[list[np.ndarray], torch.Tensor]:
    """The studio's animate preview of ``photo``: its frames as the page gets them (PNG), and as floats."""
    app = create_app(StudioConfig(token="t", allowed_hosts=("testserver",), **settings))
    client, auth = TestClient(app), {"X-Studio-Token": "t"}
    assert client.put("/api/image/a?name=p.png", content=photo.read_bytes(), headers=auth).status_code == 200
    r = client.post("/api/animate/preview", json={"config": config}, headers=auth)
    assert r.status_code == 200, r.text
    meta = r.json()
    pngs = []
    for k in range(meta["frames"]):
        f = client.get(f"/api/animate/frame?gen={meta['generation']}&k={k}", headers=auth)
        assert f.status_code == 200
        pngs.append(iio.imread(io.BytesIO(f.content)))
    return pngs, app.state.studio.animate_frames


def test_cli_and_studio_make_the_same_frames(tmp_path, photo):
    config = tmp_path / "anim.json"
    config.write_text(json.dumps(CONFIG))
    out = tmp_path / "frames"
    assert main(["animate", str(photo), "-o", f"{out}/", "--config", str(config), "--quiet"]) == 0
    cli = [iio.imread(p) for p in sorted(out.iterdir())]
    pngs, floats = studio_frames(photo, CONFIG)
    assert len(cli) == len(pngs) == CONFIG["steps"] + 1
    assert np.abs(cli[-1].astype(int) - cli[0].astype(int)).mean() > 2  # the brushes moved something
    for a, b in zip(cli, pngs):
        assert a.shape == b.shape == (40, 56, 3)
        assert np.abs(a.astype(int) - b.astype(int)).max() <= 1  # 8-bit rounding at most
    # and both are the library's pipeline, run directly
    direct = torch.stack(list(animate_frames(parse_config(CONFIG), read_image(photo))))
    torch.testing.assert_close(floats, direct, atol=1e-6, rtol=0)


def test_cli_and_studio_agree_when_the_photo_is_shrunk(tmp_path, photo):
    out = tmp_path / "frames"
    config = tmp_path / "anim.json"
    config.write_text(json.dumps(CONFIG))
    assert main(["animate", str(photo), "-o", f"{out}/", "--config", str(config), "--max-size", "28", "-q"]) == 0
    cli = [iio.imread(p) for p in sorted(out.iterdir())]
    pngs, _ = studio_frames(photo, CONFIG, animate_preview_size=28)
    assert cli[0].shape == (20, 28, 3)
    for a, b in zip(cli, pngs, strict=True):
        assert np.abs(a.astype(int) - b.astype(int)).max() <= 1


def test_frames_match_fluid_warp_and_stream(photo):
    cfg = parse_config(CONFIG)
    image = read_image(photo)
    frames = animate_frames(cfg, image)
    first = next(frames)
    torch.testing.assert_close(first, image[0])  # frame 0 is the photo itself
    assert torch.is_grad_enabled()  # the pipeline's no_grad does not leak into the caller between frames
    rest = torch.stack(list(frames))
    assert rest.shape == (cfg.steps, 3, 40, 56) and not rest.requires_grad
    b = cfg.brushes
    forces = Brushes(
        centers=[p.position for p in b],
        directions=[p.direction for p in b],
        radius=[p.radius for p in b],
        amplitude=[p.amplitude for p in b],
        frequency=[p.frequency for p in b],
        phase=[p.phase for p in b],
    )

    warp = FluidWarp(cfg.grid, cfg.steps, cfg.dt, build_viscosity(cfg, cfg.grid, (40, 56)))
    with torch.no_grad():
        expected = warp(image, forces)[0, 1:]  # (T, C, H, W)
    torch.testing.assert_close(rest, expected, atol=1e-5, rtol=0)


def test_bad_input_raises_before_the_first_frame(tmp_path, photo):
    write_image(tmp_path / "mask.png", torch.ones(1, 8, 8))
    cfg = parse_config({**CONFIG, "viscosity": {"mask": "mask.png"}}, base_dir=tmp_path)
    with pytest.raises(ValueError, match="mask"):
        animate_frames(cfg, read_image(photo))  # no next(): the generator has not started
    with pytest.raises(ValueError, match="brush"):
        animate_frames(AnimationConfig(), read_image(photo))
    with pytest.raises(ValueError, match="image"):
        animate_frames(parse_config(CONFIG), torch.full((1, 3, 8, 8), float("nan")))


def test_rescaled_config_follows_the_coordinate_module():
    cfg = parse_config(CONFIG)
    size, small = (40, 56), (20, 28)
    sx, sy = scale_factor(size, small, dtype=torch.float64).tolist()
    moved = cfg.rescaled(sx, sy)
    before = torch.tensor([b.position for b in cfg.brushes], dtype=torch.float64)
    after = torch.tensor([b.position for b in moved.brushes], dtype=torch.float64)
    torch.testing.assert_close(after, rescale_points(before, scale_factor(size, small, dtype=torch.float64)))
    torch.testing.assert_close(rescale_points(after, torch.tensor([sx, sy], dtype=torch.float64), inverse=True), before)
    assert [b.radius for b in moved.brushes] == [4.0, 3.0]


def test_config_json_round_trips():
    cfg = parse_config(CONFIG)
    assert parse_config(json.loads(json.dumps(config_json(cfg)))) == cfg
    assert parse_config(config_json(AnimationConfig())) == AnimationConfig()


def test_a_brush_or_region_outside_the_picture_is_said_to_change_nothing(photo):
    image = read_image(photo)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the brushes and the region of CONFIG lie on the 56 x 40 picture
        animate_frames(parse_config(CONFIG), image)
    far = {**CONFIG, "brushes": [{**CONFIG["brushes"][0], "position": [900, 900]}, CONFIG["brushes"][1]]}
    far["viscosity"] = {**CONFIG["viscosity"], "regions": [{"position": [-40, 10], "radius": 5, "value": 4}]}
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        frames = list(animate_frames(parse_config(far), image))
    said = sorted(str(w.message) for w in caught)
    assert len(said) == 2 and said[0].startswith("brush 0 at (900, 900), radius 8 px, lies outside the 56 x 40")
    assert said[1].startswith("viscosity region 0 at (-40, 10), radius 5 px, lies outside"), said
    near = {**CONFIG, "brushes": [{**CONFIG["brushes"][0], "position": [70, 20]}]}  # 14.5 px beyond: reaches in
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        animate_frames(parse_config(near), image)
    assert len(frames) == CONFIG["steps"] + 1
