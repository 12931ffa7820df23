"""The studio's HTTP API through Starlette's TestClient: the security checks and error handling."""

from __future__ import annotations

import io
import threading
import time
import warnings

import httpx  # noqa: F401  (starlette's TestClient needs it; both are in the [test] extra)
import numpy as np
import pytest
import torch
import torch.nn.functional as F
from PIL import Image

with warnings.catch_warnings():  # newer Starlette suggests httpx2 for its TestClient; httpx still works
    warnings.simplefilter("ignore")
    from starlette.testclient import TestClient

from torchfluidwarp.apps.studio import StudioConfig, create_app, loopback_hosts
from torchfluidwarp.apps.studio.jobs import LatestOnly, Superseded
from torchfluidwarp.apps.studio.server import add_arguments, main
from torchfluidwarp.io import read_points
from torchfluidwarp.morph import morph

TOKEN = "test-token"
AUTH = {"X-Studio-Token": TOKEN}
FAST = {"grid": 16, "steps": 4, "control": 4}
PA = [[10.0, 10.0], [50.0, 12.0], [30.0, 50.0], [20.0, 30.0]]
PB = [[12.0, 11.0], [48.0, 14.0], [31.0, 47.0], [22.0, 33.0]]


def png_bytes(seed: int, size: int = 64) -> bytes:
    rng = np.random.default_rng(seed)
    buf = io.BytesIO()
    Image.fromarray((rng.random((size, size, 3)) * 255).astype(np.uint8)).save(buf, "PNG")
    return buf.getvalue()


def make_client(tmp_path=None, **overrides) -> TestClient:
    overrides.setdefault("preview_iter", 5)  # fast tests: the fits' quality is not what is checked here
    config = StudioConfig(token=TOKEN, allowed_hosts=("testserver",), save_dir=tmp_path, **overrides)
    return TestClient(create_app(config))


@pytest.fixture
def client(tmp_path) -> TestClient:
    c = make_client(tmp_path / "exports")
    (tmp_path / "exports").mkdir()
    for slot, seed in (("a", 0), ("b", 1)):
        assert c.put(f"/api/image/{slot}?name={slot}.png", content=png_bytes(seed), headers=AUTH).status_code == 200
    return c


@pytest.mark.parametrize("path", ["/", "/static/studio.js", "/api/state", "/api/image/a"])
def test_token_required(client, path):
    assert client.get(path).status_code == 403
    assert client.get(path + "?token=wrong").status_code == 403
    assert client.get(path, headers={"X-Studio-Token": "wrong"}).status_code == 403
    assert client.get(f"{path}?token={TOKEN}").status_code == 200
    assert client.get(path, headers=AUTH).status_code == 200


def test_page_carries_token_to_its_files(client):
    html = client.get(f"/?token={TOKEN}").text
    assert f"static/studio.js?token={TOKEN}" in html and f"static/studio.css?token={TOKEN}" in html
    assert "http://" not in html and "https://" not in html  # no CDN: works offline


@pytest.mark.parametrize("host", ["evil.example:8765", "127.0.0.1.evil.example", "localhost", ""])
def test_bad_host_refused(client, host):
    r = client.get(f"/?token={TOKEN}", headers={"host": host})
    assert r.status_code == 403
    assert "host" in r.json()["error"]


def test_loopback_hosts():
    assert loopback_hosts(8765) == ("127.0.0.1:8765", "localhost:8765", "[::1]:8765")
    assert loopback_hosts(80, "192.168.1.5")[-1] == "192.168.1.5:80"
    assert loopback_hosts(80, "fe80::1")[-1] == "[fe80::1]:80"


def test_oversized_upload_refused(tmp_path):
    c = make_client(max_upload=1000)
    r = c.put("/api/image/a?name=a.png", content=png_bytes(0), headers=AUTH)  # ~12 kB > 1000 bytes
    assert r.status_code == 413
    assert "too large" in r.json()["error"]
    assert c.put("/api/image/a?name=a.png", content=png_bytes(0, size=8), headers=AUTH).status_code == 200


def test_oversized_streamed_upload_refused():
    c = make_client(max_upload=1000)

    def chunks():  # no Content-Length: the limit is enforced while reading
        for _ in range(20):
            yield b"x" * 100

    r = c.put("/api/image/a", content=chunks(), headers=AUTH)
    assert r.status_code == 413


def test_non_image_then_valid_upload(client):
    r = client.put("/api/image/b?name=notes.txt", content=b"not an image at all", headers=AUTH)
    assert r.status_code == 400
    message = r.json()["error"]
    assert "notes.txt" in message and "not a readable image" in message and "\n" not in message
    r = client.put("/api/image/b?name=b.png", content=png_bytes(3), headers=AUTH)
    assert r.status_code == 200
    assert r.json()["images"]["b"]["width"] == 64


def test_an_upload_the_reader_warns_of_says_so(client):
    # an animated GIF: its first frame is the image, and the response carries the reader's warning, naming the
    # upload, for the page to show; a plain picture carries none
    rng = np.random.default_rng(5)
    frames = [Image.fromarray((rng.random((40, 48, 3)) * 255).astype(np.uint8)) for _ in range(3)]
    buf = io.BytesIO()
    frames[0].save(buf, "GIF", save_all=True, append_images=frames[1:])
    r = client.put("/api/image/b?name=clip.gif", content=buf.getvalue(), headers=AUTH)
    assert r.status_code == 200
    assert r.json()["images"]["b"]["width"] == 48 and r.json()["images"]["b"]["height"] == 40
    (said,) = r.json()["warnings"]
    assert "'clip.gif' holds 3 frames" in said and "only its first was read" in said
    r = client.put("/api/image/b?name=b.png", content=png_bytes(3), headers=AUTH)
    assert r.json()["warnings"] == []


@pytest.mark.parametrize(
    "name", ["../escape.pts", "../../etc/passwd.pts", "/tmp/abs.pts", "sub/../../x.pts", "..\\win.pts", "C:/x.pts"]
)
def test_save_path_traversal_refused(client, tmp_path, name):
    r = client.post(
        "/api/points/export", json={"points": PA, "format": "pts", "save": True, "name": name}, headers=AUTH
    )
    assert r.status_code == 400
    assert "save folder" in r.json()["error"]
    written = {p.name for p in tmp_path.rglob("*") if p.is_file()}
    assert not written


def test_save_never_overwrites(client, tmp_path):
    body = {"points": PA, "format": "pts", "save": True, "name": "a.pts"}
    r = client.post("/api/points/export", json=body, headers=AUTH)
    assert r.status_code == 200
    saved = tmp_path / "exports" / "a.pts"
    assert r.json()["saved"] == str(saved.resolve())
    assert read_points(saved).tolist() == PA
    before = saved.read_bytes()
    body["points"] = PB
    r = client.post("/api/points/export", json=body, headers=AUTH)
    assert r.status_code == 400 and "already exists" in r.json()["error"]
    assert saved.read_bytes() == before
    assert sorted(p.name for p in saved.parent.iterdir()) == ["a.pts"]  # no temporary left behind


def test_save_symlink_escape_refused(client, tmp_path):
    outside = tmp_path / "outside"
    outside.mkdir()
    (tmp_path / "exports" / "link").symlink_to(outside)
    r = client.post(
        "/api/points/export", json={"points": PA, "format": "pts", "save": True, "name": "link/x.pts"}, headers=AUTH
    )
    assert r.status_code == 400
    assert not any(outside.iterdir())


def test_save_needs_save_dir():
    c = make_client()
    r = c.post("/api/points/export", json={"points": PA, "format": "csv", "save": True, "name": "a.csv"}, headers=AUTH)
    assert r.status_code == 400 and "--save-dir" in r.json()["error"]


@pytest.mark.parametrize("fmt", ["pts", "json", "csv"])
def test_points_download_roundtrip(client, tmp_path, fmt):
    r = client.post("/api/points/export", json={"points": PA, "format": fmt, "name": f"a.{fmt}"}, headers=AUTH)
    assert r.status_code == 200
    assert f'filename="a.{fmt}"' in r.headers["content-disposition"]
    path = tmp_path / f"down.{fmt}"
    path.write_bytes(r.content)
    assert read_points(path).tolist() == PA


def test_points_import_count_and_values(client):
    pts = b"version: 1\nn_points: 2\n{\n1 2\n3 4\n}\n"
    r = client.post("/api/points/b/import?name=b.pts&count=4", content=pts, headers=AUTH)
    assert r.status_code == 400 and "2 points" in r.json()["error"] and "4" in r.json()["error"]
    r = client.post("/api/points/b/import?name=b.pts&count=2", content=pts, headers=AUTH)
    assert r.status_code == 200 and r.json()["points"] == [[1, 2], [3, 4]]
    r = client.post("/api/points/b/import?name=b.json", content=b"[[1, 2], [3, NaN]]", headers=AUTH)
    assert r.status_code == 400 and "non-finite" in r.json()["error"]
    r = client.post("/api/points/b/import?name=b.txt", content=b"1 2", headers=AUTH)
    assert r.status_code == 400


@pytest.mark.parametrize(
    "bad",
    [
        '{"points_a": [[1.0, NaN], [2, 2]], "points_b": [[1.0, 1.0], [3, 3]]}',  # Python's json reads NaN
        '{"points_a": [[1.0, Infinity], [2, 2]], "points_b": [[1.0, 1.0], [3, 3]]}',
        "not json",
        {"points_a": PA, "points_b": PB[:3]},
        {"points_a": [[1e6, 3.0]] + PA[1:], "points_b": PB},
        {"points_a": PA, "points_b": PB, "settings": {"inverse": "magic"}},
        {"points_a": PA, "points_b": PB, "settings": {"grid": 10**6}},
    ],
)
def test_bad_morph_requests(client, bad):
    if isinstance(bad, str):
        r = client.post("/api/morph/preview", content=bad.encode(), headers=AUTH)
    else:
        r = client.post("/api/morph/preview", json=bad, headers=AUTH)
    assert r.status_code == 400
    assert r.json()["error"] and "\n" not in r.json()["error"]


@pytest.mark.slow
def test_morph_preview_frames_and_warm_start(client):
    body = {"points_a": PA, "points_b": PB, "settings": FAST}
    r = client.post("/api/morph/preview", json=body, headers=AUTH)
    assert r.status_code == 200, r.text
    meta = r.json()
    assert meta["frames"] == 9 and len(meta["trajectories"]) == 4 and len(meta["alignment"]) == 3
    assert meta["let_go"] == [False] * 4  # nothing crosses: every mark met, and the mean is over them all
    assert abs(meta["mean_error"] - sum(meta["error"]) / 4) < 1e-9
    for kind in ("blend", "forward", "backward", "jacobian"):
        img = client.get(f"/api/morph/frame?gen={meta['generation']}&k=4&kind={kind}", headers=AUTH)
        assert img.status_code == 200 and img.content[:4] == b"\x89PNG"
    state = client.get("/api/state", headers=AUTH).json()
    assert state["points"]["a"] == PA and state["points"]["b"] == PB
    body["points_b"] = PB[:3] + [[25.0, 35.0]]
    r2 = client.post("/api/morph/preview", json=body, headers=AUTH)
    assert r2.status_code == 200 and r2.json()["generation"] == meta["generation"] + 1
    # a 3 x 3 lattice with marks 0 and 1 swapped between A and B (as tests/morph/test_morph.py's): the morph
    # lets one go so as not to fold, and the mean error is over the rest
    lattice = [[x, y] for y in (14.0, 32.0, 50.0) for x in (14.0, 32.0, 50.0)]
    moved = [[x + 1.0, y + 1.5] for x, y in lattice]
    crossed = {**body, "points_a": lattice, "points_b": [moved[1], moved[0], *moved[2:]]}
    swapped = client.post("/api/morph/preview", json=crossed, headers=AUTH).json()
    gone = [i for i, g in enumerate(swapped["let_go"]) if g]
    assert gone and set(gone) <= {0, 1}
    kept = [e for e, g in zip(swapped["error"], swapped["let_go"]) if not g]
    assert abs(swapped["mean_error"] - sum(kept) / len(kept)) < 1e-9 and swapped["mean_error"] < 1
    # the older generation's frames are gone
    assert client.get(f"/api/morph/frame?gen={meta['generation']}&k=0", headers=AUTH).status_code == 410


def test_a_preview_places_b_of_another_shape_as_the_morph_does_never_stretched(tmp_path):
    # A 64 x 64, B 96 x 48 (twice as tall as wide): the preview's last frame is B on A's canvas by one factor (the
    # library's morph, frame 1), not B squashed to A's shape, as the preview showed it before
    client = make_client(tmp_path, preview_size=32)  # previews at half size: B shrunk by the same factor
    coarse = torch.rand(1, 3, 6, 3, generator=torch.Generator().manual_seed(3))  # smooth: resampling agrees
    smooth = F.interpolate(coarse, size=(96, 48), mode="bicubic", align_corners=False).clamp(0, 1)[0]
    b_pixels = (smooth.permute(1, 2, 0).numpy() * 255).round().astype(np.uint8)
    buf = io.BytesIO()
    Image.fromarray(b_pixels).save(buf, "PNG")
    assert client.put("/api/image/a?name=a.png", content=png_bytes(0), headers=AUTH).status_code == 200
    assert client.put("/api/image/b?name=b.png", content=buf.getvalue(), headers=AUTH).status_code == 200
    pb = [[x * 0.75, 16.0 + y * 0.75] for x, y in PA]  # inside B, the same layout
    meta = client.post("/api/morph/preview", json={"points_a": PA, "points_b": pb, "settings": FAST}, headers=AUTH)
    assert meta.status_code == 200, meta.text
    meta = meta.json()
    assert meta["size"] == [32, 32]
    last = client.get(f"/api/morph/frame?gen={meta['generation']}&k={meta['frames'] - 1}&kind=blend", headers=AUTH)
    shown = np.asarray(Image.open(io.BytesIO(last.content)).convert("RGB"), dtype=np.float64) / 255
    a = torch.from_numpy(np.asarray(Image.open(io.BytesIO(png_bytes(0))), dtype=np.float32) / 255).permute(2, 0, 1)
    b = torch.from_numpy(b_pixels.astype(np.float32) / 255).permute(2, 0, 1)
    small = F.interpolate(a[None], size=(32, 32), mode="area")[0]
    placed = morph(small, b, torch.tensor(PA) / 2, torch.tensor(pb), frames=2, progress=False).frames[-1]
    expected = placed.permute(1, 2, 0).double().numpy()
    assert np.abs(shown - expected).mean() < 0.03  # B placed, up to the preview's shrunk copy and 8 bits
    squashed = F.interpolate(b[None], size=(32, 32), mode="area")[0].permute(1, 2, 0).double().numpy()
    assert np.abs(shown - squashed).mean() > 0.1  # and not B squashed to A's shape


def test_animate_preview_and_config(client):
    cfg = {
        "brushes": [{"position": [30, 30], "direction": [0, -1], "radius": 8, "frequency": 0.1, "amplitude": 1.0}],
        "viscosity": {"base": 0.0, "regions": [{"position": [10, 10], "radius": 5, "value": 4}]},
        "grid": [16, 16],
        "steps": 4,
        "fps": 12,
    }
    r = client.post("/api/animate/preview", json={"config": cfg}, headers=AUTH)
    assert r.status_code == 200, r.text
    assert r.json()["frames"] == 5
    r = client.post("/api/animate/export", json={"config": cfg, "format": "json"}, headers=AUTH)
    assert r.status_code == 200
    from torchfluidwarp.apps.animate import parse_config

    assert parse_config(r.json()) == parse_config(cfg)
    bad = {**cfg, "viscosity": {"mask": "/etc/passwd"}}
    r = client.post("/api/animate/preview", json={"config": bad}, headers=AUTH)
    assert r.status_code == 400 and "mask" in r.json()["error"]
    r = client.post("/api/animate/preview", json={"config": {**cfg, "brushes": []}}, headers=AUTH)
    assert r.status_code == 400


def test_latest_only_supersedes_stale_requests():
    worker = LatestOnly()
    started, release = threading.Event(), threading.Event()
    ran: list[int] = []
    results: dict[int, object] = {}

    def job(n: int):
        def fn():
            ran.append(n)
            if n == 0:
                started.set()
                release.wait(5)
            return n

        return fn

    def call(n: int, ticket: int):
        try:
            results[n] = worker.run("fit", job(n), ticket)[1]
        except Superseded:
            results[n] = "superseded"

    threads = []
    for n in range(4):  # 0 starts; 1 and 2 queue behind it and go stale; 3 is the latest
        t = threading.Thread(target=call, args=(n, worker.ticket("fit")))
        t.start()
        threads.append(t)
        if n == 0:
            assert started.wait(5)  # 0 holds the slot before any newer ticket exists, however busy the machine
        else:
            time.sleep(0.05)  # 1 and 2 reach the slot's queue (they are superseded whether or not they do)
    release.set()
    for t in threads:
        t.join(5)
    assert ran == [0, 3]
    assert results == {0: "superseded", 1: "superseded", 2: "superseded", 3: 3}


def test_main_parses_arguments(capsys):
    import argparse

    p = argparse.ArgumentParser()
    add_arguments(p)
    ns = p.parse_args(["a.png", "b.png", "--points-a", "a.pts", "--port", "0", "--no-browser", "--save-dir", "out"])
    assert (ns.image_a, ns.image_b, ns.points_a, ns.port, ns.no_browser, ns.save_dir, ns.host) == (
        "a.png",
        "b.png",
        "a.pts",
        0,
        True,
        "out",
        "127.0.0.1",
    )
    assert main(["--help"]) == 0
    assert main(["missing.png", "--no-browser"]) == 2
    assert "missing.png" in capsys.readouterr().err


@pytest.mark.parametrize(
    ("name", "new"),
    [
        ("LatestOnly", "torchfluidwarp.apps.studio.jobs"),
        ("Superseded", "torchfluidwarp.apps.studio.jobs"),
        ("TOKEN_HEADER", "torchfluidwarp.apps.studio.guard"),
        ("MAX_UPLOAD", "torchfluidwarp.apps.studio.config"),
        ("config_json", "torchfluidwarp.apps.animate"),
    ],
)
def test_names_moved_out_of_studio_app_live_in_one_home_only(name, new):
    import importlib

    import torchfluidwarp.apps.studio.app as app

    assert getattr(importlib.import_module(new), name) is not None
    with pytest.raises(AttributeError):  # no deprecated alias left behind (#30: one home per name)
        getattr(app, name)
