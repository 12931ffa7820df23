"""The studio's page in a real browser (Playwright driving the system Chromium).

Needs ``/usr/bin/chromium`` (``apt-get install -y chromium``); Playwright's own browser download is not used.
Small images (64 x 64), grid 16 and 4 steps keep the fits short. The screenshot test writes into a temporary
folder, so a test run leaves the checkout as it found it; with ``TORCHFLUIDWARP_REFRESH_SCREENSHOTS=1`` it
refreshes the README's screenshots in ``docs/_static`` instead.
"""

from __future__ import annotations

import os
import time
from pathlib import Path

import httpx
import numpy as np
import pytest
import starlette  # noqa: F401  (starlette, uvicorn and playwright: the [test] extra)
import torch
import torch.nn.functional as F
import uvicorn  # noqa: F401
from PIL import Image
from playwright import sync_api  # no `playwright install` needed: the system Chromium is used

CHROMIUM = Path("/usr/bin/chromium")
if not CHROMIUM.exists():
    pytest.skip(
        f"Chromium not found at {CHROMIUM}: install it with `apt-get install -y chromium`", allow_module_level=True
    )

from torchfluidwarp.apps.studio import StudioConfig, create_app, loopback_hosts, serve_in_thread  # noqa: E402
from torchfluidwarp.apps.studio.server import free_port  # noqa: E402
from torchfluidwarp.io import read_image, read_points  # noqa: E402

TOKEN = "browser-test-token"
DOCS_STATIC = Path(__file__).resolve().parents[2] / "docs" / "_static"
PAIRS_A = [(12, 14), (50, 10), (30, 52), (20, 33)]
PAIRS_B = [(15, 12), (47, 16), (33, 49), (24, 30)]
WAIT_MS = 120_000  # fits on a busy 2-core CI machine can take a while


def pattern_png(path: Path, seed: int, size: int = 64) -> Path:
    """A smooth, structured test picture (colour ramps and a few discs) so that warps show."""
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:size, 0:size] / size
    img = np.stack([x, y, 0.5 + 0.5 * np.sin(6 * x + 4 * y + seed)], -1)
    for _ in range(5):
        cx, cy, r = rng.random(3) * [1, 1, 0.15] + [0, 0, 0.05]
        img[(x - cx) ** 2 + (y - cy) ** 2 < r * r] = rng.random(3)
    Image.fromarray((img * 255).astype(np.uint8)).save(path)
    return path


@pytest.fixture(scope="module")
def browser():
    with sync_api.sync_playwright() as p:
        b = p.chromium.launch(executable_path=str(CHROMIUM), args=["--no-sandbox"])
        yield b
        b.close()


@pytest.fixture
def studio():
    """A studio server in a thread on a free port, with no images: ``(base_url, app)``."""
    port = free_port()
    config = StudioConfig(token=TOKEN, allowed_hosts=loopback_hosts(port), preview_iter=10)
    app = create_app(config)
    with serve_in_thread(app, port=port):
        yield f"http://127.0.0.1:{port}", app


def server_state(base: str) -> dict:
    return httpx.get(f"{base}/api/state", headers={"X-Studio-Token": TOKEN}, timeout=30).json()


def content_box(page, selector: str) -> dict:
    """The canvas's content box in CSS pixels, and its image size."""
    return page.evaluate(
        """(sel) => {
        const c = document.querySelector(sel), r = c.getBoundingClientRect(), s = getComputedStyle(c);
        const f = (k) => parseFloat(s[k]);
        return {left: r.left + f('borderLeftWidth'), top: r.top + f('borderTopWidth'),
                width: r.width - f('borderLeftWidth') - f('borderRightWidth'),
                height: r.height - f('borderTopWidth') - f('borderBottomWidth')};
    }""",
        selector,
    )


def css_point(box: dict, size: tuple[int, int], p: tuple[float, float]) -> tuple[float, float]:
    """Where the centre of image pixel ``p`` is on the screen (CSS pixels)."""
    W, H = size
    return box["left"] + (p[0] + 0.5) * box["width"] / W, box["top"] + (p[1] + 0.5) * box["height"] / H


def set_value(page, selector: str, value: str) -> None:
    page.fill(selector, value)
    page.dispatch_event(selector, "change")


def wait_idle(page, previews: int) -> None:
    """Wait until at least ``previews`` previews were drawn and none is in flight."""
    page.wait_for_function(
        f"() => window.studio.previews >= {previews} && !document.body.classList.contains('busy')", timeout=WAIT_MS
    )


def open_page(browser, base: str, dpr: float):
    context = browser.new_context(
        device_scale_factor=dpr, viewport={"width": 1280, "height": 860}, accept_downloads=True
    )
    page = context.new_page()
    page.goto(f"{base}/?token={TOKEN}")
    page.wait_for_function("() => document.body.dataset.ready === 'true'", timeout=WAIT_MS)
    page.evaluate("() => { window.studio.autoRefine = false; }")  # one preview per edit: deterministic waits
    return context, page


def load_pair(page, tmp_path: Path) -> None:
    page.set_input_files("#file-a", str(pattern_png(tmp_path / "a.png", 1)))
    page.wait_for_function("() => window.studio.images.a && document.querySelector('#canvas-a').style.aspectRatio")
    page.set_input_files("#file-b", str(pattern_png(tmp_path / "b.png", 2)))
    page.wait_for_function("() => window.studio.images.b && document.querySelector('#canvas-b').style.aspectRatio")
    set_value(page, "#set-grid", "16")
    set_value(page, "#set-steps", "4")
    set_value(page, "#set-control", "4")


@pytest.mark.parametrize("dpr", [1, 2])
def test_points_preview_export_and_errors(browser, studio, tmp_path, dpr):
    base, _ = studio
    context, page = open_page(browser, base, dpr)
    try:
        load_pair(page, tmp_path)
        box_a, box_b = content_box(page, "#canvas-a"), content_box(page, "#canvas-b")
        for pa, pb in zip(PAIRS_A, PAIRS_B):
            page.mouse.click(*css_point(box_a, (64, 64), pa))
            page.mouse.click(*css_point(box_b, (64, 64), pb))

        # the server received exactly the clicked pixels
        deadline = time.monotonic() + 30
        while len(server_state(base)["points"]["a"]) < 4 and time.monotonic() < deadline:
            time.sleep(0.1)
        state = server_state(base)
        got_a, got_b = np.array(state["points"]["a"]), np.array(state["points"]["b"])
        assert got_a.shape == (4, 2) and got_b.shape == (4, 2)
        assert np.abs(got_a - np.array(PAIRS_A)).max() < 0.5
        assert np.abs(got_b - np.array(PAIRS_B)).max() < 0.5

        # moving a point changes the previewed frame
        wait_idle(page, 1)
        page.wait_for_timeout(400)  # let a last debounced preview start, if any
        wait_idle(page, 1)
        before = page.evaluate("() => document.querySelector('#canvas-m').toDataURL()")
        generation = int(page.get_attribute("#canvas-m", "data-generation"))
        previews = page.evaluate("() => window.studio.previews")
        assert page.is_hidden("#error"), page.inner_text("#error")
        box_b = content_box(page, "#canvas-b")  # where B is now, should anything above it have moved
        x, y = css_point(box_b, (64, 64), PAIRS_B[2])
        page.mouse.move(x, y)
        page.mouse.down()
        page.mouse.move(x + 0.15 * box_b["width"], y - 0.1 * box_b["width"], steps=4)
        page.mouse.up()
        wait_idle(page, previews + 1)
        page.wait_for_function(f"() => +document.querySelector('#canvas-m').dataset.generation > {generation}")
        after = page.evaluate("() => document.querySelector('#canvas-m').toDataURL()")
        assert after != before
        moved = np.array(server_state(base)["points"]["b"][2])
        assert np.abs(moved - np.array(PAIRS_B[2])).max() > 3

        # export A's points as .pts and read them back
        with page.expect_download() as info:
            page.click("#export-pts-a")
        path = tmp_path / "exported.pts"
        info.value.save_as(path)
        assert info.value.suggested_filename == "a.pts"
        np.testing.assert_allclose(read_points(path).numpy(), got_a, atol=1e-4)

        # a non-image: the page says so, without moving the panes, and the next valid upload works
        box_before = content_box(page, "#canvas-a")
        page.set_input_files("#file-b", files=[{"name": "notes.png", "mimeType": "image/png", "buffer": b"not a png"}])
        page.wait_for_selector("#error:not([hidden])")
        assert "notes.png" in page.inner_text("#error")
        assert content_box(page, "#canvas-a") == box_before
        # an animated GIF: its first frame is loaded, and the page shows what the reader warned of
        frames = [Image.open(pattern_png(tmp_path / f"f{i}.png", 4 + i)).convert("RGB") for i in range(3)]
        frames[0].save(tmp_path / "clip.gif", save_all=True, append_images=frames[1:])
        version = server_state(base)["images"]["b"]["version"]
        page.set_input_files("#file-b", str(tmp_path / "clip.gif"))
        page.wait_for_function(f"() => window.studio.images.b && window.studio.images.b.version > {version}")
        page.wait_for_selector("#error:not([hidden])")
        assert "'clip.gif' holds 3 frames" in page.inner_text("#error")
        version = server_state(base)["images"]["b"]["version"]
        page.set_input_files("#file-b", str(pattern_png(tmp_path / "b2.png", 3)))
        page.wait_for_function(f"() => window.studio.images.b && window.studio.images.b.version > {version}")
        assert page.is_hidden("#error")
    finally:
        context.close()


def test_one_image_alone_is_not_an_error(browser, studio, tmp_path):
    """Loading A before B is the normal order: the page waits for B instead of reporting a missing image."""
    base, _ = studio
    context, page = open_page(browser, base, 1)
    try:
        page.set_input_files("#file-a", str(pattern_png(tmp_path / "a.png", 1)))
        page.wait_for_function("() => window.studio.images.a && window.studio.syncs >= 1", timeout=WAIT_MS)
        page.wait_for_timeout(300)  # a report, had there been one, would be on the page by now
        assert page.is_hidden("#error"), page.inner_text("#error")
        assert server_state(base)["images"]["b"] is None
    finally:
        context.close()


def test_animate_brush_preview(browser, studio, tmp_path):
    base, _ = studio
    context, page = open_page(browser, base, 1)
    try:
        page.set_input_files("#file-a", str(pattern_png(tmp_path / "a.png", 1)))
        page.wait_for_function("() => window.studio.images.a")
        page.click("#tab-animate")
        set_value(page, "#a-grid", "16")
        set_value(page, "#a-steps", "4")
        box = content_box(page, "#canvas-photo")
        x, y = css_point(box, (64, 64), (32, 36))
        page.mouse.move(x, y)
        page.mouse.down()
        page.mouse.move(x, y - 0.1 * box["height"], steps=3)
        page.mouse.up()
        page.wait_for_function("() => document.querySelector('#anim-info').dataset.frames", timeout=WAIT_MS)
        assert page.get_attribute("#anim-info", "data-frames") == "5"  # steps + 1
        assert page.evaluate("() => window.studio.animPreviews") >= 1
        with page.expect_download() as info:
            page.click("#a-export-json")
        path = tmp_path / "anim.json"
        info.value.save_as(path)
        from torchfluidwarp.apps.animate import load_config

        cfg = load_config(path)
        assert cfg.steps == 4 and len(cfg.brushes) == 1
        assert abs(cfg.brushes[0].position[0] - 32) < 0.5 and abs(cfg.brushes[0].position[1] - 36) < 0.5
    finally:
        context.close()


@pytest.mark.slow
def test_screenshots(browser, tmp_path):
    """Both modes on the bundled samples (downscaled so the fit is quick), saved into a temporary folder (or into
    docs/_static with TORCHFLUIDWARP_REFRESH_SCREENSHOTS=1)."""
    shots = DOCS_STATIC if os.environ.get("TORCHFLUIDWARP_REFRESH_SCREENSHOTS") == "1" else tmp_path
    from torchfluidwarp.data import load_sample, load_sample_points

    size = 192
    images, points = {}, {}
    for slot, name in (("a", "astronaut"), ("b", "cat")):
        img = F.interpolate(
            load_sample(name), size=(size, size), mode="bilinear", antialias=True, align_corners=False
        ).clamp(0, 1)
        images[slot] = (img, f"{name}.png")
        points[slot] = (load_sample_points(name) + 0.5) * (size / 512) - 0.5
    port = free_port()
    app = create_app(
        StudioConfig(token=TOKEN, allowed_hosts=loopback_hosts(port), preview_iter=15), images=images, points=points
    )
    with serve_in_thread(app, port=port):
        context, page = open_page(browser, f"http://127.0.0.1:{port}", 1)
        try:
            set_value(page, "#set-steps", "6")  # the natural method (the page's default) on the default grid
            wait_idle(page, 1)
            page.wait_for_timeout(300)
            wait_idle(page, 1)
            page.evaluate(
                "() => { const s = document.querySelector('#time'); s.value = String(Math.floor(s.max / 2)); "
                "s.dispatchEvent(new Event('input')); }"
            )
            page.wait_for_timeout(500)
            shots.mkdir(parents=True, exist_ok=True)
            page.screenshot(path=str(shots / "studio_morph.png"))

            page.click("#tab-animate")
            set_value(page, "#a-grid", "24")
            set_value(page, "#a-steps", "24")
            box = content_box(page, "#canvas-photo")
            for (px, py), (dx, dy) in (((96, 128), (0, -14)), ((60, 70), (-8, 6))):
                x, y = css_point(box, (size, size), (px, py))
                page.mouse.move(x, y)
                page.mouse.down()
                page.mouse.move(x + dx * box["width"] / size, y + dy * box["height"] / size, steps=3)
                page.mouse.up()
            page.check("input[name='tool'][value='stiff']")
            x, y = css_point(box, (size, size), (130, 60))
            page.mouse.move(x, y)
            page.mouse.down()
            page.mouse.move(x + 20, y + 15, steps=4)
            page.mouse.up()
            page.wait_for_function("() => window.studio.animPreviews >= 1", timeout=WAIT_MS)
            page.wait_for_timeout(1500)
            page.screenshot(path=str(shots / "studio_animate.png"))
        finally:
            context.close()
    for name in ("studio_morph.png", "studio_animate.png"):
        assert Image.open(shots / name).size[0] >= 1000


def test_newest_preview_survives_an_out_of_order_ticket(browser, tmp_path):
    """The page's newest preview, refused as superseded because the server numbered another request after it
    (parallel connections can arrive in either order), is sent again and drawn."""
    images = {s: (read_image(pattern_png(tmp_path / f"{s}.png", seed)), f"{s}.png") for s, seed in (("a", 1), ("b", 2))}
    points = {"a": torch.tensor(PAIRS_A, dtype=torch.float32), "b": torch.tensor(PAIRS_B, dtype=torch.float32)}
    port = free_port()
    app = create_app(
        StudioConfig(token=TOKEN, allowed_hosts=loopback_hosts(port), preview_iter=5), images=images, points=points
    )
    worker = app.state.worker
    with serve_in_thread(app, port=port):
        context, page = open_page(browser, f"http://127.0.0.1:{port}", 1)
        try:
            set_value(page, "#set-grid", "16")
            set_value(page, "#set-steps", "4")
            wait_idle(page, 1)
            page.wait_for_timeout(300)
            wait_idle(page, 1)
            previews = page.evaluate("() => window.studio.previews")
            with worker._slot:  # the fit slot is busy, so the page's request waits for it with its ticket
                before = worker.current("morph")
                set_value(page, "#set-steps", "5")
                deadline = time.monotonic() + 30
                while worker.current("morph") == before and time.monotonic() < deadline:
                    time.sleep(0.02)
                assert worker.current("morph") == before + 1, "the page's preview did not reach the server"
                worker.ticket("morph")  # a request the server numbered after the page's newest one
            wait_idle(page, previews + 1)
            assert worker.current("morph") >= before + 3  # the page sent its newest preview again
            assert page.evaluate("() => window.studio.previews") == previews + 1
            assert page.is_hidden("#error")
        finally:
            context.close()
