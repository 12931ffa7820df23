"""Tests for torchfluidwarp.io: images, landmark points and animations on disk."""

from __future__ import annotations

import importlib.util
import json
import sys
from pathlib import Path

import imageio.v3 as iio
import numpy as np
import pytest
import torch
from PIL import GifImagePlugin, Image

from torchfluidwarp.io import (
    _decode,
    animation,
    check_point_counts,
    encode_animation,
    image_shape,
    images,
    read_image,
    read_image_bytes,
    read_points,
    write_animation,
    write_image,
    write_points,
)


def random_image(gen: torch.Generator, shape: tuple[int, ...]) -> torch.Tensor:
    """Random values on the 8-bit grid, so a PNG round trip is exact."""
    return torch.randint(0, 256, shape, generator=gen).float() / 255.0


def listing(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir())


# ---------------------------------------------------------------------------------------------- images


@pytest.mark.parametrize("channels", [1, 3, 4])
def test_png_round_trip_is_exact(tmp_path, gen, channels):
    image = random_image(gen, (1, channels, 7, 9))
    path = write_image(tmp_path / "im.png", image)
    back = read_image(path)
    assert back.shape == (1, channels, 7, 9) and back.dtype == torch.float32
    assert torch.equal(back, image)
    assert torch.equal(read_image_bytes(path.read_bytes()), image)
    assert listing(tmp_path) == ["im.png"]


def test_write_image_accepts_chw(tmp_path, gen):
    image = random_image(gen, (3, 5, 6))
    assert torch.equal(read_image(write_image(tmp_path / "a.png", image))[0], image)


def test_sixteen_bit_png(tmp_path):
    array = (np.arange(20, dtype=np.uint16).reshape(4, 5) * 3000).astype(np.uint16)
    iio.imwrite(tmp_path / "deep.png", array)
    back = read_image(tmp_path / "deep.png", dtype=torch.float64)
    assert back.shape == (1, 1, 4, 5)
    torch.testing.assert_close(back[0, 0], torch.from_numpy(array / 65535.0))


def test_channel_conversions(tmp_path, gen):
    rgba = random_image(gen, (1, 4, 4, 5))
    write_image(tmp_path / "rgba.png", rgba)
    assert torch.equal(read_image(tmp_path / "rgba.png", channels=3), rgba[:, :3])
    gray = random_image(gen, (1, 1, 4, 5))
    write_image(tmp_path / "gray.png", gray)
    assert torch.equal(read_image(tmp_path / "gray.png", channels=3), gray.expand(1, 3, 4, 5))
    rgb4 = read_image(tmp_path / "gray.png", channels=4)
    assert torch.equal(rgb4[:, 3], torch.ones(1, 4, 5))
    luma = read_image(tmp_path / "rgba.png", channels=1)
    expected = 0.299 * rgba[:, 0] + 0.587 * rgba[:, 1] + 0.114 * rgba[:, 2]
    torch.testing.assert_close(luma[:, 0], expected)


@pytest.mark.parametrize(
    "orientation, upright",
    [
        (1, lambda a: a),
        (3, lambda a: np.rot90(a, 2)),
        (6, lambda a: np.rot90(a, -1)),  # a phone held upright: stored turned left, shown turned a quarter right
        (8, lambda a: np.rot90(a, 1)),
        (2, lambda a: a[:, ::-1]),
        (4, lambda a: a[::-1]),
        (5, lambda a: a.transpose(1, 0, 2)),  # mirrored about the main diagonal
        (7, lambda a: a[::-1, ::-1].transpose(1, 0, 2)),  # mirrored about the other diagonal
    ],
)
@pytest.mark.parametrize("kind", ["rgb", "grey", "palette", "palette with a transparent colour"])
def test_a_photograph_reads_upright_as_its_exif_orientation_says(tmp_path, gen, orientation, upright, kind):
    # every viewer shows a picture as its EXIF orientation tag says; read as stored, a phone's portrait would come
    # out sideways (its faces unfound, its marks on the wrong pixels). A palette picture is turned as its colours
    # (imageio's own turn mirrored its colour channels instead of its columns: orientations 2, 4, 5 and 7)
    exif = Image.Exif()
    exif[0x0112] = orientation
    path = tmp_path / "photo.png"
    if kind.startswith("palette"):
        colours = (torch.rand(8, 3, generator=gen) * 255).round().to(torch.uint8).numpy()
        index = torch.randint(0, 8, (6, 10), generator=gen).to(torch.uint8).numpy()
        picture = Image.fromarray(index, mode="P")
        picture.putpalette(colours.tobytes())
        stored = colours[index]
        options = {"transparency": 3} if kind.endswith("colour") else {}
        if options:
            stored = np.concatenate([stored, np.where(index == 3, 0, 255).astype(np.uint8)[..., None]], -1)
        picture.save(path, exif=exif, **options)
    else:
        shape = (6, 10, 3) if kind == "rgb" else (6, 10)
        stored = (torch.rand(shape, generator=gen) * 255).round().to(torch.uint8).numpy()
        Image.fromarray(stored).save(path, exif=exif)
    image = read_image(path)
    turned = np.ascontiguousarray(upright(stored if stored.ndim == 3 else stored[..., None]))
    want = torch.from_numpy(turned).permute(2, 0, 1)[None].float() / 255
    assert image.shape == want.shape
    torch.testing.assert_close(image, want, atol=0, rtol=0)
    torch.testing.assert_close(read_image_bytes(path.read_bytes()), want, atol=0, rtol=0)
    assert image_shape(path) == tuple(want.shape[1:])


def test_gray_alpha_png_reads_as_rgba(tmp_path):
    Image.new("LA", (3, 2), (128, 64)).save(tmp_path / "la.png")
    image = read_image(tmp_path / "la.png")
    assert image.shape == (1, 4, 2, 3)
    torch.testing.assert_close(image[0, :, 0, 0], torch.tensor([128, 128, 128, 64]) / 255.0)


@pytest.mark.parametrize("name", ["anim.gif", "anim.webp", "anim.png", "pages.tif"])
def test_a_file_of_several_frames_gives_its_first_and_says_how_many(tmp_path, gen, name):
    """An animated GIF, WebP or PNG and a multi-page TIFF: the first frame's pixels (a multi-page TIFF was refused
    as an "unsupported pixel layout" of all its pages stacked), and a warning that names the file and the count."""
    frames = [(random_image(gen, (12, 10, 3)) * 255).to(torch.uint8).numpy() for _ in range(3)]
    pictures = [Image.fromarray(f) for f in frames]
    extra = {"lossless": True} if name.endswith(".webp") else {}
    pictures[0].save(tmp_path / name, save_all=True, append_images=pictures[1:], **extra)
    with pytest.warns(UserWarning, match=rf"{name}' holds 3 frames .*only its first was read"):
        image = read_image(tmp_path / name)
    assert image.shape == (1, 3, 12, 10)
    if not name.endswith(".gif"):  # a GIF's palette changes the colours; the others keep them exactly
        want = torch.from_numpy(frames[0]).permute(2, 0, 1)[None].float() / 255
        torch.testing.assert_close(image, want, atol=0, rtol=0)
    else:  # the first frame, not another: nearer it than any other frame
        errors = [float((image[0].permute(1, 2, 0) - torch.from_numpy(f) / 255).abs().mean()) for f in frames]
        assert errors[0] < 0.05 < min(errors[1:])
    with pytest.warns(UserWarning, match="image bytes .* holds 3 frames"):
        read_image_bytes((tmp_path / name).read_bytes())
    with pytest.warns(UserWarning, match="image 'upload' holds 3 frames"):  # an upload's name, as the studio's
        read_image_bytes((tmp_path / name).read_bytes(), name="upload")


@pytest.mark.parametrize("name", ["one.gif", "one.png", "one.tif", "one.webp", "one.jpg"])
def test_a_file_of_one_frame_reads_without_a_warning(tmp_path, gen, name, recwarn):
    Image.fromarray((random_image(gen, (6, 5, 3)) * 255).to(torch.uint8).numpy()).save(tmp_path / name)
    assert read_image(tmp_path / name).shape == (1, 3, 6, 5)
    assert not [w for w in recwarn if "frames" in str(w.message)]


def _tiff(path: Path, kind: str, rgb: np.ndarray) -> np.ndarray:
    """Write ``rgb`` ``(H, W, 3)`` uint8 as a TIFF of ``kind``; return the ``(H, W, C)`` pixels it shows (0..1)."""
    tifffile = pytest.importorskip("tifffile")
    grey = rgb[..., 0]
    if kind == "palette":
        Image.fromarray(rgb).convert("P").save(path)
        return np.asarray(Image.open(path).convert("RGB")) / 255.0
    if kind == "min-is-white":  # stored inverted: 0 is white
        tifffile.imwrite(path, grey, photometric="miniswhite")
        return (255 - grey[..., None]) / 255.0
    if kind == "cmyk":
        Image.fromarray(rgb).convert("CMYK").save(path)
        return np.asarray(Image.open(path).convert("RGB")) / 255.0
    if kind == "lzw":  # tifffile decodes LZW only with the optional imagecodecs; it refused these
        Image.fromarray(rgb).save(path, compression="tiff_lzw")
        return rgb / 255.0
    if kind == "planes":  # R, G, B one plane after another
        tifffile.imwrite(path, np.moveaxis(rgb, -1, 0), photometric="rgb", planarconfig="separate")
        return rgb / 255.0
    wide = rgb.astype(np.uint16) * 257 + np.arange(rgb.size, dtype=np.uint16).reshape(rgb.shape) % 251
    tifffile.imwrite(path, wide, photometric="rgb")  # "16-bit": the low bits are not 8-bit's
    return wide / 65535.0


@pytest.mark.parametrize("kind", ["palette", "min-is-white", "cmyk", "planes", "lzw", "16-bit"])
def test_a_tiff_reads_as_the_picture_it_shows(tmp_path, gen, kind):
    """tifffile gives a TIFF's stored samples: a palette's indices, grey inverted, CMYK as four channels (read as
    RGBA), colour planes as a (3, H, W) "unsupported layout", and it refused LZW without imagecodecs. Each is now
    the picture; 16-bit colour keeps its 16 bits."""
    rgb = (random_image(gen, (9, 7, 3)) * 255).to(torch.uint8).numpy()
    want = _tiff(tmp_path / "x.tif", kind, rgb)
    image = read_image(tmp_path / "x.tif", dtype=torch.float64)
    assert image.shape == (1, want.shape[-1], 9, 7)
    torch.testing.assert_close(image[0].permute(1, 2, 0), torch.from_numpy(want), atol=1e-7, rtol=0)


def test_a_tiff_of_colour_planes_is_measured_by_its_tags_before_decoding(tmp_path, gen):
    """Its page's shape is (3, H, W): the pixel count checked against max_pixels is H * W, not 3 * H."""
    _tiff(tmp_path / "x.tif", "planes", (random_image(gen, (20, 30, 3)) * 255).to(torch.uint8).numpy())
    with pytest.raises(ValueError, match=r"30 x 20 = 600 pixels, more than max_pixels=599") as info:
        read_image(tmp_path / "x.tif", max_pixels=599)
    assert str(info.value).endswith("; pass a larger max_pixels to read it")  # the advice, to a Python caller
    assert info.value.explain({}).endswith("more than max_pixels=599")  # none to one without the argument (studio)
    assert read_image(tmp_path / "x.tif", max_pixels=600).shape == (1, 3, 20, 30)


def _kinds(folder: Path, gen: torch.Generator) -> list[Path]:
    """One file of each kind whose header and decoded shape could disagree."""
    rgb = (random_image(gen, (9, 7, 3)) * 255).to(torch.uint8).numpy()
    Image.fromarray(rgb).save(folder / "plain.jpg")
    turned = Image.fromarray(rgb)
    exif = turned.getexif()
    exif[0x0112] = 6  # stored turned a quarter
    turned.save(folder / "turned.jpg", exif=exif)
    Image.fromarray(rgb[..., 0]).save(folder / "grey.png")
    Image.fromarray(rgb[..., :2], "LA").save(folder / "grey-alpha.png")
    Image.fromarray(rgb).convert("P").save(folder / "palette.png")
    Image.fromarray(rgb).convert("P").save(folder / "palette-transparent.png", transparency=0)
    Image.fromarray(rgb).convert("CMYK").save(folder / "cmyk.jpg")
    Image.fromarray(np.dstack([rgb, rgb[..., :1]]), "RGBA").save(folder / "rgba.png")
    Image.fromarray(rgb).save(folder / "frames.gif", save_all=True, append_images=[Image.fromarray(rgb[::-1])])
    for kind in ("palette", "min-is-white", "cmyk", "planes", "lzw", "16-bit"):
        _tiff(folder / f"{kind}.tif", kind, rgb)
    return sorted(folder.iterdir())


def test_image_shape_reads_from_the_header_the_shape_read_image_gives(tmp_path, gen, recwarn):
    for path in _kinds(tmp_path, gen):
        assert image_shape(path) == tuple(read_image(path).shape[1:]), path.name
    assert image_shape(tmp_path / "turned.jpg") == (3, 7, 9)  # upright: the stored 9 x 7 turned a quarter
    with pytest.raises(ValueError, match=r"missing\.png.*no such file"):
        image_shape(tmp_path / "missing.png")
    (tmp_path / "junk.png").write_bytes(b"not an image")
    with pytest.raises(ValueError, match=r"junk\.png.*not a readable image"):
        image_shape(tmp_path / "junk.png")


def test_read_image_errors_name_the_path(tmp_path):
    missing = tmp_path / "missing.png"
    with pytest.raises(ValueError, match="missing.png.*no such file"):
        read_image(missing)
    junk = tmp_path / "junk.png"
    junk.write_bytes(b"this is not a png")
    with pytest.raises(ValueError, match="junk.png.*not a readable image") as info:
        read_image(junk)
    assert "\n" not in str(info.value)
    assert str(info.value).endswith("(no image format recognises its contents)"), info.value  # not imageio's words
    with pytest.raises(ValueError, match="image bytes"):
        read_image_bytes(b"garbage")
    with pytest.raises(ValueError, match="image 'notes.txt'.*not a readable image"):
        read_image_bytes(b"garbage", name="notes.txt")
    with pytest.raises(TypeError, match="name must be a str"):
        read_image_bytes(b"garbage", name=3)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="channels"):
        read_image(junk, channels=2)


@pytest.mark.parametrize("shape", [(4, 5), (2, 3, 4, 5), (1, 2, 4, 5), (1, 1, 1, 4, 5)])
def test_write_image_rejects_bad_shapes(tmp_path, shape):
    with pytest.raises(ValueError, match="image"):
        write_image(tmp_path / "bad.png", torch.zeros(shape))
    assert listing(tmp_path) == []


def test_write_image_rejects_nan(tmp_path):
    with pytest.raises(ValueError, match="non-finite"):
        write_image(tmp_path / "nan.png", torch.full((1, 3, 3), float("nan")))


# ---------------------------------------------------------------------------------------------- points


POINTS = torch.tensor([[12.5, 40.25], [0.0, 511.0], [255.1234, 17.0001], [-3.5, 100.75]])


@pytest.mark.parametrize("suffix", [".pts", ".json", ".csv"])
def test_points_round_trip(tmp_path, suffix):
    path = write_points(tmp_path / f"face{suffix}", POINTS)
    back = read_points(path)
    assert back.shape == (4, 2) and back.dtype == torch.float32
    torch.testing.assert_close(back, POINTS, atol=1e-4, rtol=0)
    assert listing(tmp_path) == [f"face{suffix}"]


def test_pts_layout(tmp_path):
    write_points(tmp_path / "a.pts", POINTS[:2])
    assert (tmp_path / "a.pts").read_text() == "version: 1\nn_points: 2\n{\n12.5 40.25\n0 511\n}\n"


@pytest.mark.parametrize(
    ("name", "text"),
    [
        ("list.json", "[[1, 2], [3.5, 4.5]]"),
        ("object.json", '{"points": [[1, 2], [3.5, 4.5]]}'),
        ("header.csv", "x,y\n1,2\n3.5,4.5\n"),
        ("noheader.csv", "1,2\n\n3.5, 4.5\n"),
        ("bom.csv", "\ufeffx,y\n1,2\n3.5,4.5\n"),  # a spreadsheet's "CSV UTF-8" starts with a byte-order mark
        ("bomnoheader.csv", "\ufeff1,2\n3.5,4.5\n"),
        ("named.csv", "id,label,X,Y,visible\n0,eye,1,2,1\n1,eye,3.5,4.5,0\n"),
        ("yx.csv", "y,x\n2,1\n4.5,3.5\n"),  # columns read by their names, in any order
        ("bom.pts", "\ufeffversion: 1\nn_points: 2\n{\n1 2\n3.5 4.5\n}\n"),
        ("spaced.pts", "version: 1\nn_points:  2\n{\n  1 2\n3.5\t4.5\n}\n\n"),
    ],
)
def test_read_points_accepted_forms(tmp_path, name, text):
    (tmp_path / name).write_text(text)
    assert read_points(tmp_path / name).tolist() == [[1.0, 2.0], [3.5, 4.5]]


@pytest.mark.parametrize(
    ("name", "text", "why"),
    [
        ("count.pts", "version: 1\nn_points: 3\n{\n1 2\n3 4\n}\n", "n_points: 3 but the file has 2"),
        ("nobrace.pts", "version: 1\nn_points: 1\n1 2\n", "expected 'key: value'"),
        ("noclose.pts", "version: 1\nn_points: 1\n{\n1 2\n", "no '}'"),
        ("noheader.pts", "{\n1 2\n}\n", "n_points"),
        ("three.pts", "version: 1\nn_points: 1\n{\n1 2 3\n}\n", "expected 2 values"),
        ("word.pts", "version: 1\nn_points: 1\n{\n1 y\n}\n", "not a number"),
        ("nan.pts", "version: 1\nn_points: 1\n{\nnan 2\n}\n", "non-finite"),
        ("bad.json", "[[1, 2],", "invalid JSON"),
        ("item.json", "[[1, 2, 3]]", "point 0"),
        ("string.json", '[["1", 2]]', "point 0"),
        ("key.json", '{"pts": [[1, 2]]}', "points"),
        ("inf.json", "[[Infinity, 2]]", "non-finite"),
        ("three.csv", "1,2,3\n", "expected 2 values"),
        ("word.csv", "x,y\n1,2\na,b\n", "not a number"),
        ("unnamed.csv", "a,b\n1,2\n", "a header row must name the columns x and y once each, got ['a', 'b']"),
        ("twice.csv", "x,y,x\n1,2,3\n", "name the columns x and y once each, got ['x', 'y', 'x']"),
        ("short.csv", "id,x,y\n0,1\n", "line 2: 2 fields under a header of 3 columns"),
        ("long.csv", "x,y\n0,10,20\n", "line 2: 3 fields under a header of 2 columns"),  # not read as id,x
    ],
)
def test_malformed_points_raise(tmp_path, name, text, why):
    (tmp_path / name).write_text(text)
    with pytest.raises(ValueError, match=name) as info:
        read_points(tmp_path / name)
    assert why in str(info.value)


def test_points_path_errors(tmp_path):
    with pytest.raises(ValueError, match="no such file"):
        read_points(tmp_path / "missing.pts")
    with pytest.raises(ValueError, match=r"face\.txt.*\.pts, \.json, \.csv"):
        read_points(tmp_path / "face.txt")
    with pytest.raises(ValueError, match="suffix"):
        write_points(tmp_path / "face.txt", POINTS)
    with pytest.raises(ValueError, match="points"):
        write_points(tmp_path / "face.pts", torch.zeros(3, 3))
    assert listing(tmp_path) == []


def test_check_point_counts_names_both_counts():
    check_point_counts(torch.zeros(5, 2), torch.ones(5, 2))
    with pytest.raises(ValueError, match="^points_a has 68 points but points_b has 20$"):
        check_point_counts(torch.zeros(68, 2), torch.zeros(20, 2))
    with pytest.raises(ValueError, match="src.pts has 3 points but dst.pts has 4"):
        check_point_counts(torch.zeros(3, 2), torch.zeros(4, 2), "src.pts", "dst.pts")


# ------------------------------------------------------------------------------------------ animations


def frames_with_repeats(gen: torch.Generator) -> torch.Tensor:
    """7 small frames (fewer colours than a GIF palette holds): a, a, a, b, b, c, c."""
    a, b, c = random_image(gen, (3, 3, 8, 10)).unbind(0)
    return torch.stack([a, a, a, b, b, c, c])


def gif_frames(data: bytes | Path) -> np.ndarray:
    return iio.imread(data, index=None, extension=".gif")  # (T, H, W, 3)


def test_gif_keeps_every_frame_including_repeats(tmp_path, gen):
    frames = frames_with_repeats(gen)
    path = write_animation(tmp_path / "anim.gif", frames, fps=10)
    back = gif_frames(path)
    assert back.shape == (7, 8, 10, 3)
    expected = (frames * 255).round().to(torch.uint8).permute(0, 2, 3, 1).numpy()
    np.testing.assert_array_equal(back, expected)
    with Image.open(path) as gif:
        assert gif.n_frames == 7
        assert gif.info["loop"] == 0 and gif.info["duration"] == 100
    assert listing(tmp_path) == ["anim.gif"]


def test_gif_of_identical_frames_and_gray(tmp_path, gen):
    still = random_image(gen, (1, 1, 6, 6)).expand(5, 1, 6, 6)
    back = gif_frames(write_animation(tmp_path / "still.gif", still))
    assert back.shape == (5, 6, 6, 3)
    assert all(np.array_equal(back[0], frame) for frame in back)


def test_gif_of_larger_frames_keeps_count(tmp_path, gen):
    # More colours than the palette: quantized, but repeats must still survive.
    frames = random_image(gen, (2, 3, 40, 48))
    frames = torch.stack([frames[0], frames[0], frames[1], frames[1], frames[1]])
    back = gif_frames(write_animation(tmp_path / "big.gif", frames))
    assert back.shape[0] == 5
    assert np.array_equal(back[0], back[1]) and np.array_equal(back[2], back[4])


def test_encode_animation_gif_bytes(gen):
    frames = frames_with_repeats(gen)
    data = encode_animation(frames, "gif", fps=5)
    assert data[:6] == b"GIF89a"
    assert gif_frames(data).shape[0] == 7
    with pytest.raises(ValueError, match="fmt"):
        encode_animation(frames, "webm")  # type: ignore[arg-type]


@pytest.mark.parametrize("name", ["frames/", "frames"])
def test_frames_folder(tmp_path, gen, name):
    frames = random_image(gen, (3, 4, 5, 6))
    out = write_animation(str(tmp_path / name), frames)
    assert out == tmp_path / "frames" and listing(tmp_path) == ["frames"]
    assert listing(out) == ["frame_0000.png", "frame_0001.png", "frame_0002.png"]
    for t in range(3):
        assert torch.equal(read_image(out / f"frame_{t:04d}.png")[0], frames[t])


def test_frames_into_existing_empty_folder(tmp_path, gen):
    (tmp_path / "out.d").mkdir()
    write_animation(tmp_path / "out.d", random_image(gen, (2, 1, 4, 4)))
    assert listing(tmp_path / "out.d") == ["frame_0000.png", "frame_0001.png"]


def test_refuses_to_overwrite(tmp_path, gen):
    frames = frames_with_repeats(gen)
    path = write_animation(tmp_path / "anim.gif", frames)
    with pytest.raises(FileExistsError, match="anim.gif.*overwrite=True"):
        write_animation(path, frames[:2])
    assert gif_frames(path).shape[0] == 7
    write_animation(path, frames[:2], overwrite=True)
    assert gif_frames(path).shape[0] == 2

    folder = write_animation(tmp_path / "frames", frames[:3])
    with pytest.raises(FileExistsError, match="frames"):
        write_animation(folder, frames[:2])
    write_animation(folder, frames[:2], overwrite=True)
    assert listing(folder) == ["frame_0000.png", "frame_0001.png"]
    assert listing(tmp_path) == ["anim.gif", "frames"]


def test_never_replaces_a_folder_of_other_files(tmp_path, gen):
    (tmp_path / "results").mkdir()
    (tmp_path / "results" / "notes.txt").write_text("keep me")
    with pytest.raises(FileExistsError, match="notes.txt"):
        write_animation(tmp_path / "results", random_image(gen, (2, 3, 4, 4)), overwrite=True)
    assert listing(tmp_path / "results") == ["notes.txt"]


@pytest.mark.parametrize("shape", [(3, 2, 4, 4), (3, 4, 4), (0, 3, 4, 4)])
@pytest.mark.parametrize("name", ["anim.gif", "frames/"])
def test_bad_frames_leave_nothing(tmp_path, shape, name):
    with pytest.raises(ValueError, match="frames"):
        write_animation(str(tmp_path / name), torch.zeros(shape))
    assert listing(tmp_path) == []


def test_failing_gif_write_leaves_old_file_and_no_temp(tmp_path, gen, monkeypatch):
    frames = frames_with_repeats(gen)
    path = write_animation(tmp_path / "anim.gif", frames)
    before = path.read_bytes()

    def broken_frame(*args, **kwargs):  # the GIF writer encodes each frame with GifImagePlugin.getdata
        raise OSError("disk full")

    monkeypatch.setattr(GifImagePlugin, "getdata", broken_frame)
    with pytest.raises(OSError, match="disk full"):
        write_animation(path, frames[:3], overwrite=True)
    with pytest.raises(OSError, match="disk full"):
        write_animation(tmp_path / "new.gif", frames)
    assert listing(tmp_path) == ["anim.gif"]
    assert path.read_bytes() == before


def test_failing_frames_write_leaves_no_folder(tmp_path, gen, monkeypatch):
    real_imwrite = animation.iio.imwrite
    calls = []

    def flaky_imwrite(uri, image, **kwargs):
        calls.append(uri)
        if len(calls) == 3:
            raise OSError("disk full")
        return real_imwrite(uri, image, **kwargs)

    monkeypatch.setattr(animation.iio, "imwrite", flaky_imwrite)
    with pytest.raises(OSError, match="disk full"):
        write_animation(tmp_path / "frames", random_image(gen, (5, 3, 4, 4)))
    assert listing(tmp_path) == []


def test_unknown_suffix_and_bad_options(tmp_path, gen):
    frames = random_image(gen, (2, 3, 4, 4))
    with pytest.raises(ValueError, match=r"\.webm"):
        write_animation(tmp_path / "a.webm", frames)
    with pytest.raises(ValueError, match="fps"):
        write_animation(tmp_path / "a.gif", frames, fps=0)
    with pytest.raises(ValueError, match="loop"):
        write_animation(tmp_path / "a.gif", frames, loop=-1)
    with pytest.raises(ValueError, match="non-finite"):
        write_animation(tmp_path / "a.gif", torch.full((2, 3, 4, 4), float("nan")))
    assert listing(tmp_path) == []


def test_mp4_without_ffmpeg_says_how_to_install(tmp_path, gen, monkeypatch):
    monkeypatch.setitem(sys.modules, "imageio_ffmpeg", None)  # makes `import imageio_ffmpeg` fail
    frames = random_image(gen, (2, 3, 4, 4))
    with pytest.raises(RuntimeError, match=r"imageio-ffmpeg: pip install 'torchfluidwarp\[video\]'"):
        write_animation(tmp_path / "a.mp4", frames)
    with pytest.raises(RuntimeError, match="imageio-ffmpeg"):
        encode_animation(frames, "mp4")
    assert listing(tmp_path) == []


def test_mp4_round_trip_frame_count(tmp_path, gen):
    import imageio_ffmpeg  # noqa: F401  (the [video] extra, which [test] pulls in)

    frames = random_image(gen, (2, 3, 15, 20))
    frames = torch.stack([frames[0], frames[0], frames[1], frames[1], frames[1]])
    path = write_animation(tmp_path / "a.mp4", frames, fps=12)
    back = iio.imread(path, plugin="FFMPEG")
    assert back.shape == (5, 16, 20, 3)  # odd height padded to even
    assert listing(tmp_path) == ["a.mp4"]


def test_an_mp4_of_rgba_frames_shows_them_over_black(tmp_path):
    # MP4 has no alpha: a transparent pixel is black whatever colour it stores (a morph's first frame stores the
    # picture's own, its middle frames none), an opaque one its colour, half alpha half its colour
    frames = torch.zeros(3, 4, 16, 16)
    frames[:, :3] = torch.tensor([1.0, 1.0, 1.0])[:, None, None]  # white stored everywhere
    frames[:, 3, :, 8:] = 1.0  # the right half opaque
    frames[:, 3, :8, :8] = 0.5  # the top-left quarter half transparent, the bottom-left fully
    path = write_animation(tmp_path / "a.mp4", frames, fps=12)
    back = iio.imread(path, plugin="FFMPEG").astype(float)  # (3, 16, 16, 3)
    assert back[:, 10:14, 1:5].max() < 24  # transparent: black (H.264's rounding aside)
    assert back[:, 2:6, 10:14].min() > 230  # opaque white
    assert abs(back[:, 2:6, 1:5].mean() - 128) < 16  # half alpha over black


def test_json_written_as_points_object(tmp_path):
    write_points(tmp_path / "p.json", POINTS[:1])
    assert json.loads((tmp_path / "p.json").read_text()) == {"points": [[12.5, 40.25]]}


def test_frames_convert_in_chunks_identically(monkeypatch, tmp_path):
    # 7 frames in chunks of 2 (the last one short): the same bytes as one conversion of everything
    frames = torch.rand(7, 3, 5, 6, generator=torch.Generator().manual_seed(3))
    frames[0, 0, 0, 0], frames[1, 0, 0, 0] = -0.2, 1.3  # clamped
    expected = (frames.double().clamp(0, 1) * 255).round().to(torch.uint8).permute(0, 2, 3, 1).numpy()
    monkeypatch.setattr(images, "_CONVERT_BYTES", 2 * 8 * 3 * 5 * 6)
    np.testing.assert_array_equal(images._uint8_frames(frames, "frames"), expected)
    write_animation(tmp_path / "out/", frames, fps=5)
    last = iio.imread(sorted((tmp_path / "out").iterdir())[6])
    np.testing.assert_array_equal(last, expected[6])


def test_a_cameras_jpeg_with_a_preview_is_one_picture(tmp_path, gen, recwarn):
    """Pillow opens a JPEG that carries a smaller preview or gain map (an MPF block) as an MPO of 2 frames: it is
    one photograph, read without a frames warning; two pictures of one size (a stereo MPO) still warn."""
    rgb = (random_image(gen, (16, 12, 3)) * 255).to(torch.uint8).numpy()
    photo = Image.fromarray(rgb)
    photo.save(tmp_path / "camera.jpg", format="MPO", save_all=True, append_images=[Image.fromarray(rgb[::4, ::4])])
    assert Image.open(tmp_path / "camera.jpg").n_frames == 2  # what made it warn
    assert read_image(tmp_path / "camera.jpg").shape == (1, 3, 16, 12)
    assert not [w for w in recwarn if "frames" in str(w.message)]
    photo.save(tmp_path / "stereo.jpg", format="MPO", save_all=True, append_images=[Image.fromarray(rgb[::-1])])
    with pytest.warns(UserWarning, match="stereo.jpg' holds 2 frames"):
        read_image(tmp_path / "stereo.jpg")


def test_a_tiff_with_a_thumbnail_page_is_one_picture(tmp_path, gen, recwarn):
    tifffile = pytest.importorskip("tifffile")
    rgb = (random_image(gen, (16, 12, 3)) * 255).to(torch.uint8).numpy()
    with tifffile.TiffWriter(tmp_path / "scan.tif") as tiff:
        tiff.write(rgb, photometric="rgb")
        tiff.write(rgb[::4, ::4], photometric="rgb", subfiletype=1)  # a reduced-resolution page
    image = read_image(tmp_path / "scan.tif")
    torch.testing.assert_close(image[0].permute(1, 2, 0), torch.from_numpy(rgb) / 255.0, atol=0, rtol=0)
    assert not [w for w in recwarn if "frames" in str(w.message)]


@pytest.mark.parametrize("compression", [None, "tiff_lzw"])
def test_a_turned_tiff_reads_upright_whatever_its_compression(tmp_path, gen, compression):
    """tifffile ignores the Orientation tag, Pillow (which reads LZW without imagecodecs) follows it: the same
    picture came back stored as it is or turned, by its compression. Now upright both ways, and image_shape
    agrees."""
    rgb = (random_image(gen, (9, 7, 3)) * 255).to(torch.uint8).numpy()
    picture = Image.fromarray(rgb)
    exif = picture.getexif()
    exif[0x0112] = 6  # stored turned a quarter anticlockwise: shown turned clockwise
    picture.save(tmp_path / "turned.tif", exif=exif, **({"compression": compression} if compression else {}))
    image = read_image(tmp_path / "turned.tif")
    upright = np.rot90(rgb, k=-1)  # orientation 6: turn 90 degrees clockwise to show it
    torch.testing.assert_close(image[0].permute(1, 2, 0), torch.from_numpy(upright.copy()) / 255.0, atol=0, rtol=0)
    assert image_shape(tmp_path / "turned.tif") == (3, 7, 9)


def test_a_sixteen_bit_min_is_white_tiff_is_not_inverted(tmp_path):
    tifffile = pytest.importorskip("tifffile")
    stored = np.arange(20 * 3, dtype=np.uint16).reshape(3, 20) * 1000
    tifffile.imwrite(tmp_path / "x.tif", stored, photometric="miniswhite")
    image = read_image(tmp_path / "x.tif", dtype=torch.float64)
    np.testing.assert_allclose(image[0, 0].numpy(), (65535 - stored) / 65535.0, atol=1e-12)


@pytest.mark.parametrize("writer", ["tifffile", "pillow"])
def test_a_tiff_whose_width_is_zero_is_the_files_fault(tmp_path, gen, writer):
    """Its ImageWidth tag set to 0: tifffile raises ZeroDivisionError on the one written by tifffile, and read the
    one Pillow wrote as an empty (4, 0) picture. Both are an InputError naming the file, from read_image and
    image_shape alike (``morph --pairs`` plans with the latter)."""
    tifffile = pytest.importorskip("tifffile")
    rgb = (random_image(gen, (4, 5, 3)) * 255).to(torch.uint8).numpy()
    if writer == "tifffile":
        tifffile.imwrite(tmp_path / "ok.tif", rgb, photometric="rgb")
    else:
        Image.fromarray(rgb).save(tmp_path / "ok.tif")
    data = bytearray((tmp_path / "ok.tif").read_bytes())
    assert data[:4] == b"II*\x00"  # little-endian TIFF: its first directory's entries, 12 bytes each
    ifd = int.from_bytes(data[4:8], "little")
    entries = [ifd + 2 + 12 * i for i in range(int.from_bytes(data[ifd : ifd + 2], "little"))]
    width = next(e for e in entries if int.from_bytes(data[e : e + 2], "little") == 256)  # ImageWidth
    data[width + 8 : width + 12] = bytes(4)  # its value: 0
    (tmp_path / "bad.tif").write_bytes(bytes(data))
    why = "not a readable image" if writer == "tifffile" else "it holds no pixels"
    with pytest.raises(ValueError, match=rf"bad\.tif.*{why}"):
        read_image(tmp_path / "bad.tif")
    with pytest.raises(ValueError, match=rf"bad\.tif.*{why}"):
        image_shape(tmp_path / "bad.tif")


def test_without_pillow_heif_a_heic_is_refused_with_what_to_install(tmp_path, monkeypatch):
    """Told apart by its suffix or, as bytes, by its "ftyp" brand, before any decoder sees it."""
    heic = b"\x00\x00\x00\x18ftypheic\x00\x00\x00\x00mif1heic" + bytes(64)
    (tmp_path / "photo.heic").write_bytes(heic)
    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name == "pillow_heif" else real(name, *a))
    for read in (read_image, image_shape):
        with pytest.raises(ValueError, match=r"photo\.heic.*HEIC/HEIF.*pip install 'torchfluidwarp\[heic\]'"):
            read(tmp_path / "photo.heic")
    with pytest.raises(ValueError, match=r"image bytes.*HEIC/HEIF.*pillow-heif"):
        read_image_bytes(heic)


def test_an_avif_whose_major_brand_is_mif1_is_not_taken_for_heic(tmp_path, gen):
    """AVIF files may name HEIF's "mif1" as their major brand and "avif" among the compatible ones: Pillow reads
    them, pillow-heif (no AV1 decoder) does not, so they must not be sent to it, nor refused for want of it.
    (Where pillow-heif is installed, imageio's Pillow plugin registers its opener with Pillow for every process,
    and that opener claims such files: the classification is checked here, not a read.)"""
    rgb = (random_image(gen, (8, 8, 3)) * 255).to(torch.uint8).numpy()
    Image.fromarray(rgb).save(tmp_path / "x.avif", quality=100)
    data = bytearray((tmp_path / "x.avif").read_bytes())
    assert data[4:12] == b"ftypavif" and b"mif1" in data[16 : int.from_bytes(data[:4], "big")]
    data[8:12] = b"mif1"  # the major brand; "avif" stays among the compatible ones
    assert not _decode._heif_brand(bytes(data)) and not _decode._heif_brand(tmp_path / "x.avif")
    assert _decode._heif_brand(b"\x00\x00\x00\x18ftypmif1\x00\x00\x00\x00mif1heic" + bytes(8))
