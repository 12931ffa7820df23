"""Bad input to torchfluidwarp.io gets a clear error that names the argument or file, and leaves no file behind
and no output clobbered (issue #19): huge, malformed and broken files; bad frame rates; bad paths and dtypes."""

from __future__ import annotations

import io
import math
import re
import struct
import warnings
import zlib
from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import Image

from torchfluidwarp.io import (
    MAX_FPS,
    MAX_IMAGE_PIXELS,
    MAX_LOOP,
    MIN_FPS,
    check_fps,
    encode_animation,
    read_image,
    read_image_bytes,
    read_points,
    resize_image,
    shrink_image,
    write_animation,
    write_image,
    write_points,
)


def listing(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir())


def png_header(width: int, height: int) -> bytes:
    """A PNG whose IHDR claims ``width x height`` RGB pixels, followed by almost no data."""

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    ihdr = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    idat = zlib.compress(b"\0" * 10)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", idat) + chunk(b"IEND", b"")


def frames3(gen: torch.Generator) -> torch.Tensor:
    return torch.randint(0, 256, (3, 3, 6, 8), generator=gen).float() / 255.0


# ---------------------------------------------------------------------------------------------- images


def test_a_png_claiming_60000_squared_is_refused_by_name_and_size(tmp_path):
    bomb = tmp_path / "bomb.png"
    bomb.write_bytes(png_header(60000, 60000))
    with pytest.raises(ValueError, match=r"bomb\.png.*3,600,000,000 pixels.*max_pixels=67,108,864"):
        read_image(bomb)
    with pytest.raises(ValueError, match=r"image bytes.*3,600,000,000 pixels"):
        read_image_bytes(bomb.read_bytes())


@pytest.mark.filterwarnings("ignore::PIL.Image.DecompressionBombWarning")
def test_a_header_above_max_pixels_is_refused_before_decoding(tmp_path):
    big = tmp_path / "big.png"
    big.write_bytes(png_header(12000, 12000))  # 144 million pixels claimed in 70 bytes
    assert 12000 * 12000 > MAX_IMAGE_PIXELS
    with pytest.raises(ValueError, match=r"big\.png.*12000 x 12000 = 144,000,000 pixels.*max_pixels=67,108,864"):
        read_image(big)


def test_max_pixels_is_the_exact_bound(tmp_path):
    path = write_image(tmp_path / "im.png", torch.rand(3, 4, 5, generator=torch.Generator().manual_seed(0)))
    assert read_image(path, max_pixels=20).shape == (1, 3, 4, 5)
    with pytest.raises(ValueError, match=r"5 x 4 = 20 pixels, more than max_pixels=19"):
        read_image(path, max_pixels=19)
    with pytest.raises(ValueError, match="max_pixels=19"):
        read_image_bytes(path.read_bytes(), max_pixels=19)
    with pytest.raises(TypeError, match="max_pixels"):
        read_image(path, max_pixels=1e9)  # type: ignore[arg-type]


def test_a_cmyk_jpeg_reads_as_rgb_not_as_rgba(tmp_path):
    path = tmp_path / "cmyk.jpg"
    Image.new("CMYK", (6, 4), (0, 255, 255, 0)).save(path, quality=100)  # red in print colours
    image = read_image(path)
    assert image.shape == (1, 3, 4, 6)
    with Image.open(path) as im:
        expected = torch.from_numpy(np.asarray(im.convert("RGB"), dtype=np.float64) / 255.0).permute(2, 0, 1)
    torch.testing.assert_close(image[0].double(), expected, rtol=0, atol=1e-7)


def test_a_palette_png_with_a_transparent_colour_keeps_its_alpha(tmp_path):
    path = tmp_path / "palette.png"
    indices = Image.frombytes("P", (3, 1), bytes([0, 1, 0]))
    indices.putpalette([255, 0, 0, 0, 0, 255] + [0] * 762)
    indices.save(path, transparency=1)
    image = read_image(path)
    assert image.shape == (1, 4, 1, 3)
    torch.testing.assert_close(image[0, :, 0, 0], torch.tensor([1.0, 0.0, 0.0, 1.0]))
    torch.testing.assert_close(image[0, 3, 0], torch.tensor([1.0, 0.0, 1.0]))


@pytest.mark.parametrize("channels", [True, 1.0, "3", 0])
def test_channels_must_be_an_int_of_1_3_or_4(tmp_path, channels):
    path = write_image(tmp_path / "im.png", torch.zeros(1, 2, 2))
    with pytest.raises(ValueError, match=rf"channels must be None, 1, 3 or 4, got {channels!r}"):
        read_image(path, channels=channels)  # type: ignore[arg-type]


def test_reading_a_folder_or_a_non_path_names_it(tmp_path):
    (tmp_path / "dir.png").mkdir()
    with pytest.raises(ValueError, match=r"dir\.png.*folder"):
        read_image(tmp_path / "dir.png")
    with pytest.raises(TypeError, match="path must be a str or os.PathLike path, got NoneType"):
        read_image(None)  # type: ignore[arg-type]


@pytest.mark.parametrize(
    ("name", "channels", "why"),
    [("a.txt", 3, "suffix '.txt'.*no image format"), ("noext", 3, "no suffix"), ("a.jpg", 4, "4 channels.*RGBA")],
)
def test_write_image_refuses_a_format_that_cannot_hold_it_and_keeps_the_old_file(tmp_path, name, channels, why):
    (tmp_path / name).write_bytes(b"old")
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the library's own error alone: no third-party warning before it
        with pytest.raises(ValueError, match=why):
            write_image(tmp_path / name, torch.rand(channels, 4, 4))
    assert listing(tmp_path) == [name] and (tmp_path / name).read_bytes() == b"old"


def test_write_image_never_replaces_a_folder(tmp_path):
    (tmp_path / "out.png").mkdir()
    (tmp_path / "out.png" / "keep.txt").write_text("keep me")
    with pytest.raises(ValueError, match=r"out\.png.*is a folder"):
        write_image(tmp_path / "out.png", torch.rand(3, 4, 4))
    assert listing(tmp_path / "out.png") == ["keep.txt"]
    with pytest.raises(ValueError, match="names no file"):
        write_image(tmp_path / "sub" / "..", torch.rand(3, 4, 4))


def test_write_image_creates_missing_parents_and_round_trips_half_precision(tmp_path):
    image = torch.randint(0, 256, (3, 5, 4), generator=torch.Generator().manual_seed(2)).float() / 255.0
    for dtype in (torch.float16, torch.bfloat16):
        path = write_image(tmp_path / "a" / "b" / f"{dtype}.png", image.to(dtype))
        assert torch.equal(read_image(path)[0], image)  # 8-bit values survive half precision's rounding


@pytest.mark.parametrize(
    ("size", "error"),
    [((0, 3), ValueError), ((-1, 3), ValueError), ((2.5, 3), ValueError), ("ab", TypeError), ((2, 3, 4), TypeError)],
)
def test_resize_image_names_a_bad_size(size, error):
    with pytest.raises(error, match="size"):
        resize_image(torch.rand(1, 3, 4, 4), size)


@pytest.mark.parametrize("shape", [(1, 0, 4, 4), (1, 3, 0, 4), (1, 3, 4, 0)])
def test_resize_image_refuses_an_empty_image(shape):
    with pytest.raises(ValueError, match=r"image must have C, H and W >= 1"):
        resize_image(torch.zeros(shape), (2, 2))


def test_resize_image_refuses_a_result_above_max_memory_before_any_work():
    with pytest.raises(ValueError, match=r"1000000 x 1000000.*TiB.*max_memory"):
        resize_image(torch.rand(1, 3, 4, 4), (10**6, 10**6))
    with pytest.raises(ValueError, match="max_memory"):
        resize_image(torch.rand(1, 3, 4, 4), (8, 8), max_memory=1000)


@pytest.mark.parametrize("dtype", [torch.float16, torch.bfloat16])
def test_resize_image_computes_half_precision_in_float32(dtype):
    image = torch.rand(2, 3, 16, 12, generator=torch.Generator().manual_seed(4)).to(dtype)
    out = resize_image(image, (7, 5))
    assert out.dtype == dtype
    reference = resize_image(image.float(), (7, 5))
    torch.testing.assert_close(out.float(), reference, rtol=0, atol=float(torch.finfo(dtype).eps))


def test_shrink_image_names_a_non_tensor():
    with pytest.raises(TypeError, match="image must be a torch.Tensor"):
        shrink_image([[0.0]], 4)  # type: ignore[arg-type]


# ---------------------------------------------------------------------------------------------- points


@pytest.mark.parametrize(
    "text", ["[" * 100_000 + "]" * 100_000, '{"points": ' + "[" * 5000 + "]" * 5000 + "}"], ids=["list", "object"]
)
def test_deeply_nested_json_is_refused_by_name(tmp_path, text):
    (tmp_path / "deep.json").write_text(text)
    with pytest.raises(ValueError, match=r"deep\.json.*nested too deeply"):
        read_points(tmp_path / "deep.json")


@pytest.mark.parametrize(
    ("name", "text", "why"),
    [
        ("bigint.json", "[[1" + "0" * 400 + ", 2]]", r"point 0: a value is too large.*\(40\d characters\)"),
        ("field.csv", "1," + "2" * 200_000 + "\n", "field larger than field limit"),
        ("longword.csv", "1," + "x" * 1000 + "\n", r"not a number in .*\(1,0\d\d characters\)"),
    ],
    ids=["bigint.json", "field.csv", "longword.csv"],
)
def test_huge_values_in_points_files_get_short_clear_errors(tmp_path, name, text, why):
    (tmp_path / name).write_text(text)
    with pytest.raises(ValueError, match=name) as info:
        read_points(tmp_path / name)
    assert len(str(info.value)) < 300 and re.search(why, str(info.value))


@pytest.mark.parametrize("dtype", [torch.int64, torch.int32, torch.bool, torch.complex64, "float32"])
def test_read_points_refuses_a_non_float_dtype_instead_of_truncating(tmp_path, dtype):
    (tmp_path / "p.csv").write_text("1.7,2.2\n")
    with pytest.raises(TypeError, match="dtype must be a floating-point torch.dtype"):
        read_points(tmp_path / "p.csv", dtype=dtype)  # type: ignore[arg-type]


def test_read_points_refuses_values_beyond_the_dtype(tmp_path):
    (tmp_path / "p.csv").write_text("1e6,2\n")
    with pytest.raises(ValueError, match=r"p\.csv.*1e\+06.*float16"):
        read_points(tmp_path / "p.csv", dtype=torch.float16)
    assert read_points(tmp_path / "p.csv", dtype=torch.float32).tolist() == [[1e6, 2.0]]


def test_max_bytes_is_the_exact_bound(tmp_path):
    path = tmp_path / "p.csv"
    path.write_text("1,2\n3,4\n")  # 8 bytes
    assert read_points(path, max_bytes=8).shape == (2, 2)
    with pytest.raises(ValueError, match=r"p\.csv.*8 bytes, more than max_bytes=7"):
        read_points(path, max_bytes=7)


def test_points_paths_name_folders_and_non_paths(tmp_path):
    (tmp_path / "dir.pts").mkdir()
    with pytest.raises(ValueError, match=r"dir\.pts.*folder"):
        read_points(tmp_path / "dir.pts")
    with pytest.raises(ValueError, match=r"dir\.pts.*is a folder"):
        write_points(tmp_path / "dir.pts", torch.zeros(2, 2))
    with pytest.raises(TypeError, match="path must be"):
        read_points(3)  # type: ignore[arg-type]
    assert listing(tmp_path) == ["dir.pts"] and listing(tmp_path / "dir.pts") == []


def test_write_points_round_trips_bfloat16_exactly(tmp_path):
    points = (torch.rand(5, 2, generator=torch.Generator().manual_seed(5)) * 300).bfloat16()
    back = read_points(write_points(tmp_path / "n" / "p.json", points), dtype=torch.float32)
    assert torch.equal(back, points.float())


# ------------------------------------------------------------------------------------------ animations

BAD_FPS = [1e-300, 0, 0.0, -1, math.nan, math.inf, -math.inf, 1e300, 0.009, 1000.5, 10**400]
FPS_IDS = [repr(f) if not isinstance(f, int) or abs(f) < 10**6 else "10**400" for f in BAD_FPS]


@pytest.mark.parametrize("fps", BAD_FPS, ids=FPS_IDS)
@pytest.mark.parametrize("name", ["a.gif", "a.mp4", "frames/"])
def test_a_bad_fps_is_refused_and_the_old_output_kept(tmp_path, gen, fps, name):
    frames = frames3(gen)
    out = write_animation(str(tmp_path / name), frames)
    before = listing(out) if out.is_dir() else out.read_bytes()
    with pytest.raises(ValueError, match="fps must be"):
        write_animation(str(tmp_path / name), frames[:1], fps=fps, overwrite=True)
    assert listing(tmp_path) == [out.name]
    assert (listing(out) if out.is_dir() else out.read_bytes()) == before


@pytest.mark.parametrize("fps", BAD_FPS, ids=FPS_IDS)
@pytest.mark.parametrize("fmt", ["gif", "mp4"])
def test_encode_animation_refuses_a_bad_fps(gen, fps, fmt):
    with pytest.raises(ValueError, match=r"fps must be"):
        encode_animation(frames3(gen), fmt, fps=fps)


@pytest.mark.parametrize("fps", [True, "10", None])
def test_fps_must_be_a_number(fps):
    with pytest.raises(TypeError, match="fps must be a number"):
        check_fps(fps)


@pytest.mark.parametrize(("fps", "duration_ms"), [(MIN_FPS, 100_000), (MAX_FPS, 10), (3, 330)])
def test_the_fps_bounds_encode_gifs(gen, fps, duration_ms):
    with Image.open(io.BytesIO(encode_animation(frames3(gen), fps=fps))) as gif:
        assert gif.n_frames == 3 and gif.info["duration"] == duration_ms


def test_loop_above_a_gifs_16_bits_is_refused_and_the_top_value_kept(tmp_path, gen):
    with pytest.raises(ValueError, match=r"loop must be at most 65535.*got 65536"):
        encode_animation(frames3(gen), loop=MAX_LOOP + 1)
    with pytest.raises(ValueError, match="loop"):
        write_animation(tmp_path / "a.gif", frames3(gen), loop=10**9)
    assert listing(tmp_path) == []
    with Image.open(write_animation(tmp_path / "a.gif", frames3(gen), loop=MAX_LOOP)) as gif:
        assert gif.info["loop"] == MAX_LOOP


def test_overwrite_must_be_a_bool_and_the_old_file_stays(tmp_path, gen):
    path = write_animation(tmp_path / "a.gif", frames3(gen))
    before = path.read_bytes()
    with pytest.raises(TypeError, match="overwrite must be a bool, got str 'no'"):
        write_animation(path, frames3(gen)[:1], overwrite="no")  # type: ignore[arg-type]
    assert path.read_bytes() == before and listing(tmp_path) == ["a.gif"]


@pytest.mark.parametrize(("path", "why"), [("", "non-empty path"), (".", "names no file"), (None, "path must be")])
def test_write_animation_names_a_bad_path(gen, path, why):
    with pytest.raises((TypeError, ValueError), match=why):
        write_animation(path, frames3(gen))  # type: ignore[arg-type]


@pytest.mark.parametrize("name", ["a.mp4", None])
def test_ffmpeg_writing_nothing_is_an_error_and_leaves_nothing(tmp_path, gen, monkeypatch, name):
    import imageio_ffmpeg  # (the [video] extra, which [test] pulls in)

    def silent_ffmpeg(*args, **kwargs):  # takes the frames, writes nothing: ffmpeg failed silently
        while True:
            yield

    monkeypatch.setattr(imageio_ffmpeg, "write_frames", silent_ffmpeg)
    with pytest.raises(RuntimeError, match=r"ffmpeg wrote no video for 3 frames of 8 x 6"):
        if name is None:
            encode_animation(frames3(gen), "mp4")
        else:
            write_animation(tmp_path / name, frames3(gen))
    assert listing(tmp_path) == []
