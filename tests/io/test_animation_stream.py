"""Streamed animation writing: an iterable of frames is written one frame at a time, as a tensor would be."""

from __future__ import annotations

import threading
import tracemalloc

import imageio.v3 as iio
import numpy as np
import pytest
import torch

from torchfluidwarp.io import encode_animation, write_animation


def frames(gen: torch.Generator, n: int = 6, c: int = 3) -> torch.Tensor:
    """``(n, c, 12, 10)`` smooth frames (a moving gradient), which a 256-colour GIF keeps to within a few levels."""
    y, x = torch.meshgrid(torch.linspace(0, 1, 12), torch.linspace(0, 1, 10), indexing="ij")
    out = torch.stack([(x + y * k / n + 0.1 * k) % 1 for k in range(n)])[:, None].expand(n, c, 12, 10)
    return (0.8 * out + 0.1 * torch.rand(n, c, 1, 1, generator=gen)).contiguous()


def decoded(path) -> np.ndarray:
    return np.asarray(iio.imread(path, index=None), dtype=np.int16)


@pytest.mark.parametrize("name", ["a.gif", "a.mp4", "frames/"])
def test_an_iterable_writes_what_the_tensor_writes(tmp_path, gen, name):
    video = frames(gen)
    whole = write_animation(tmp_path / "whole" / name, video)
    streamed = write_animation(tmp_path / "streamed" / name, (f for f in video))  # a generator: no len()
    if name.endswith("/"):
        names = sorted(p.name for p in streamed.iterdir())
        assert names == sorted(p.name for p in whole.iterdir()) and len(names) == 6
        for n in names:
            np.testing.assert_array_equal(iio.imread(whole / n), iio.imread(streamed / n))
        return
    a, b = decoded(whole), decoded(streamed)
    assert a.shape[:3] == b.shape[:3] == (6, 12, 10)
    np.testing.assert_array_equal(a, b)
    truth = np.round(video.permute(0, 2, 3, 1).numpy() * 255).astype(np.int16)
    tolerance = 4 if name.endswith(".gif") else 24  # GIF: 256 colours; MP4: lossy yuv420p
    assert np.abs(a[..., :3] - truth).mean() < tolerance


def test_gif_keeps_every_frame_repeats_included(tmp_path, gen):
    video = frames(gen, 4)
    video = torch.stack([video[0], video[0], video[1], video[1], video[1], video[2]])
    out = write_animation(tmp_path / "a.gif", iter(video), fps=20, loop=3)
    data = decoded(out)
    assert data.shape[0] == 6
    np.testing.assert_array_equal(data[0], data[1])
    np.testing.assert_array_equal(data[2], data[4])
    from PIL import Image

    with Image.open(out) as gif:
        assert gif.n_frames == 6 and gif.info["loop"] == 3 and gif.info["duration"] == 50


def test_encode_takes_an_iterable(gen):
    video = frames(gen)
    assert encode_animation(iter(video)) == encode_animation(video)


def test_folder_names_sort_past_ten_thousand_frames(tmp_path):
    out = write_animation(tmp_path / "f/", (torch.full((1, 2, 2), k / 10001) for k in range(10001)))
    names = sorted(p.name for p in out.iterdir())
    assert len(names) == 10001 and names[0] == "frame_00000.png" and names[-1] == "frame_10000.png"


@pytest.mark.parametrize("name", ["a.gif", "frames/"])
def test_a_bad_frame_midway_leaves_nothing(tmp_path, gen, name):
    video = frames(gen)

    def stream():
        yield from video[:3]
        yield torch.zeros(3, 5, 5)  # another size

    with pytest.raises(ValueError, match=r"frames\[3\] has shape \(3, 5, 5\), but frames\[0\] is \(3, 12, 10\)"):
        write_animation(tmp_path / name, stream())
    with pytest.raises(ValueError, match="frames is empty"):
        write_animation(tmp_path / name, iter([]))
    with pytest.raises(TypeError, match=r"frames\[0\] must be a \(C, H, W\) tensor"):
        write_animation(tmp_path / name, ["not a frame"])
    assert list(tmp_path.iterdir()) == []


def test_streaming_holds_one_frame_not_all(tmp_path):
    """Python-side memory of a streamed GIF stays about one frame's, whatever the frame count."""

    def peak(n: int) -> int:
        tracemalloc.start()
        write_animation(tmp_path / f"{n}.gif", (torch.full((3, 64, 64), (k % 7) / 7) for k in range(n)))
        peak = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
        return peak

    small, large = peak(5), peak(200)  # 200 frames of 64x64 RGB would be 2.4 MB as uint8
    assert large < small + 500_000


def test_a_transparent_gif_streams_in_one_frames_memory(tmp_path):
    """RGBA frames take the transparent-GIF path, which is streamed as the RGB one is."""

    def rgba(k: int) -> torch.Tensor:
        frame = torch.full((4, 64, 64), (k % 7) / 7)
        frame[3, :, : 8 + k % 40] = 0.0  # a transparent band of changing width
        frame[3, :, 8 + k % 40 :] = 1.0
        return frame

    def peak(n: int) -> int:
        tracemalloc.start()
        write_animation(tmp_path / f"t{n}.gif", (rgba(k) for k in range(n)))
        peak = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
        return peak

    small, large = peak(5), peak(200)
    assert large < small + 500_000
    alpha = iio.imread(tmp_path / "t200.gif", index=None, mode="RGBA")[..., 3]
    for k in (0, 57, 199):
        assert (alpha[k, :, : 8 + k % 40] == 0).all() and (alpha[k, :, 8 + k % 40 :] == 255).all()


@pytest.mark.parametrize("c", [3, 4])
def test_a_gif_quantized_ahead_in_threads_is_the_gif_quantized_in_turn(tmp_path, gen, monkeypatch, c):
    # frames small enough to be quantized QUANTIZE_AHEAD at a time, against the same frames quantized one by one
    # (a byte budget below one frame): the same bytes, frames in their order
    from torchfluidwarp.io import animation

    video = frames(gen, 9, c)
    quantize, threads = animation._quantize, []

    def recorded(frame, cube):
        threads.append(threading.current_thread().name)
        return quantize(frame, cube)

    monkeypatch.setattr(animation, "_quantize", recorded)
    ahead = write_animation(tmp_path / "ahead.gif", iter(video))
    assert len(threads) == 9 and all(name.startswith("gif") for name in threads)  # each frame in the pool
    threads.clear()
    monkeypatch.setattr(animation, "QUANTIZE_BYTES", 1)
    in_turn = write_animation(tmp_path / "in_turn.gif", iter(video))
    assert threads == [threading.current_thread().name] * 9  # each frame in turn, by the writer's own thread
    assert ahead.read_bytes() == in_turn.read_bytes()
    truth = np.round(video.permute(0, 2, 3, 1).numpy() * 255).astype(np.int16)
    if c == 3:
        data = decoded(ahead)
        assert data.shape[0] == 9 and np.abs(data - truth).mean(axis=(1, 2, 3)).max() < 4
    else:  # transparent where alpha < 0.5, frame by frame
        alpha = iio.imread(ahead, index=None, mode="RGBA")[..., 3]
        assert alpha.shape[0] == 9 and np.array_equal(alpha == 0, truth[..., 3] < 128)


def test_a_frame_that_fails_while_others_are_quantized_leaves_no_gif(tmp_path, gen):
    video = frames(gen, 6)

    def failing():
        yield from video[:4]
        raise RuntimeError("frame 4 could not be made")

    with pytest.raises(RuntimeError, match="frame 4 could not be made"):
        write_animation(tmp_path / "a.gif", failing())
    assert list(tmp_path.iterdir()) == []  # neither the file nor its temporary sibling


def test_a_frame_that_fails_to_quantize_in_its_thread_leaves_no_gif(tmp_path, gen, monkeypatch):
    from torchfluidwarp.io import animation

    quantize, count = animation._quantize, []

    def third_fails(frame, cube):
        count.append(1)
        if len(count) == 3:
            raise MemoryError("no room to quantize frame 2")
        return quantize(frame, cube)

    monkeypatch.setattr(animation, "_quantize", third_fails)
    with pytest.raises(MemoryError, match="frame 2"):  # raised in the pool, given to the writer's caller
        write_animation(tmp_path / "a.gif", iter(frames(gen, 6)))
    assert list(tmp_path.iterdir()) == []
