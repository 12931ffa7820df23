"""Embedded colour profiles (torchfluidwarp.io.images): a picture tagged with a wide-gamut profile is read in sRGB,
as colour-managed viewers show it; sRGB and untagged pictures are read as stored."""

from __future__ import annotations

import struct

import numpy as np
import pytest
import torch
from PIL import Image, ImageCms

from torchfluidwarp.io import read_image, read_image_bytes

# Display P3's primaries as an ICC profile gives them (adapted to D50, the profile connection space): the columns
# of its RGB -> XYZ matrix
P3_D50 = np.array([(0.5151, 0.2412, -0.0011), (0.2919, 0.6922, 0.0419), (0.1571, 0.0666, 0.7841)]).T
D50 = (0.9642, 1.0, 0.8249)
# sRGB's RGB -> XYZ matrix adapted to D50 (Bradford), as LittleCMS's built-in sRGB profile has it
SRGB_D50 = np.array(
    [[0.4360747, 0.3850649, 0.1430804], [0.2225045, 0.7168786, 0.0606169], [0.0139322, 0.0971045, 0.7141733]]
)
GAMMA = 2.2


def _s15(x: float) -> bytes:
    return struct.pack(">i", round(x * 65536))


def wide_profile(primaries: np.ndarray = P3_D50, gamma: float = GAMMA, name: bytes = b"wide test RGB") -> bytes:
    """An ICC v2 matrix/TRC RGB display profile, by default with P3's primaries and a plain 2.2 gamma, built here
    (no profile file ships with the test's dependencies)."""

    def xyz(v) -> bytes:
        return b"XYZ " + bytes(4) + b"".join(_s15(c) for c in v)

    curve = b"curv" + bytes(4) + struct.pack(">IH", 1, round(gamma * 256))
    name = name + b"\0"
    desc = b"desc" + bytes(4) + struct.pack(">I", len(name)) + name + struct.pack(">IIHB", 0, 0, 0, 0) + bytes(67)
    tags = [(b"desc", desc), (b"wtpt", xyz(D50))]
    tags += [(sig, xyz(primaries[:, i])) for i, sig in enumerate((b"rXYZ", b"gXYZ", b"bXYZ"))]
    tags += [(b"rTRC", curve), (b"gTRC", curve), (b"bTRC", curve), (b"cprt", b"text" + bytes(4) + b"none\0")]
    start = 128 + 4 + 12 * len(tags)
    table, data = struct.pack(">I", len(tags)), b""
    for sig, body in tags:
        data += bytes(-(start + len(data)) % 4)  # tags start on 4-byte boundaries
        table += sig + struct.pack(">II", start + len(data), len(body))
        data += body
    header = struct.pack(">I", start + len(data)) + b"none" + bytes([2, 0x10, 0, 0]) + b"mntrRGB XYZ " + bytes(12)
    header += b"acspAPPL" + bytes(24) + b"".join(_s15(c) for c in D50) + b"none" + bytes(44)
    assert len(header) == 128
    return header + table + data


def p3_to_srgb(pixels: np.ndarray) -> np.ndarray:
    """``(..., 3)`` 8-bit values in the profile above -> sRGB in ``[0, 1]``: decode the gamma, the profile's matrix
    to XYZ, sRGB's inverse, clipped to sRGB's gamut (relative colorimetric), sRGB's curve."""
    linear = (pixels / 255.0) ** GAMMA
    srgb = np.linalg.solve(SRGB_D50, P3_D50 @ linear.reshape(-1, 3).T).T.clip(0, 1).reshape(pixels.shape)
    return np.where(srgb <= 0.0031308, 12.92 * srgb, 1.055 * srgb ** (1 / 2.4) - 0.055)


def _pixels(gen: torch.Generator, channels: int = 3) -> np.ndarray:
    return torch.randint(0, 256, (8, 9, channels), generator=gen, dtype=torch.uint8).numpy()


@pytest.mark.parametrize("suffix", [".png", ".tif", ".webp"])
def test_a_wide_gamut_picture_is_read_in_srgb(tmp_path, gen, suffix):
    """Against the colour science written out here, to within LittleCMS's 16-bit tables and the 8-bit rounding;
    the stored values themselves are up to tens of levels away (not a no-op)."""
    stored = _pixels(gen)
    path = tmp_path / f"wide{suffix}"
    Image.fromarray(stored).save(path, icc_profile=wide_profile(), **({"lossless": True} if suffix == ".webp" else {}))
    image = read_image(path, dtype=torch.float64)[0].permute(1, 2, 0).numpy()
    want = p3_to_srgb(stored.astype(np.float64))
    assert np.abs(image - want).max() < 1.5 / 255
    assert np.abs(stored / 255.0 - want).max() > 20 / 255  # the check above could not pass on the stored values
    np.testing.assert_array_equal(read_image_bytes(path.read_bytes()).numpy(), read_image(path).numpy())


def test_the_alpha_of_a_wide_gamut_picture_is_kept(tmp_path, gen):
    stored = _pixels(gen, channels=4)
    Image.fromarray(stored, "RGBA").save(tmp_path / "wide.png", icc_profile=wide_profile())
    image = read_image(tmp_path / "wide.png", dtype=torch.float64)[0].permute(1, 2, 0).numpy()
    np.testing.assert_array_equal(image[..., 3], stored[..., 3] / 255.0)
    assert np.abs(image[..., :3] - p3_to_srgb(stored[..., :3].astype(np.float64))).max() < 1.5 / 255


def test_srgb_and_untagged_pictures_read_as_stored(tmp_path, gen, recwarn):
    stored = _pixels(gen)
    srgb = ImageCms.ImageCmsProfile(ImageCms.createProfile("sRGB")).tobytes()
    Image.fromarray(stored).save(tmp_path / "srgb.png", icc_profile=srgb)
    Image.fromarray(stored).save(tmp_path / "plain.png")
    for name in ("srgb.png", "plain.png"):
        image = read_image(tmp_path / name, dtype=torch.float64)[0].permute(1, 2, 0).numpy()
        np.testing.assert_array_equal(image, stored / 255.0)
    assert not recwarn.list


def test_a_profile_that_cannot_be_read_leaves_the_pixels_and_says_so(tmp_path, gen):
    stored = _pixels(gen)
    Image.fromarray(stored).save(tmp_path / "odd.png", icc_profile=b"not a profile" * 20)
    with pytest.warns(UserWarning, match=r"colour profile of image '.*odd\.png' could not be applied .* as sRGB"):
        image = read_image(tmp_path / "odd.png", dtype=torch.float64)
    np.testing.assert_array_equal(image[0].permute(1, 2, 0).numpy(), stored / 255.0)


def test_a_wide_gamut_heic_is_read_in_srgb(tmp_path):
    """An iPhone's photograph: HEIC in Display P3 (HEVC is lossy: a smooth picture, compared on average)."""
    pillow_heif = pytest.importorskip("pillow_heif")
    y, x = np.meshgrid(np.linspace(0, 1, 24), np.linspace(0, 1, 40), indexing="ij")
    stored = np.stack([0.2 + 0.7 * x, 0.8 - 0.6 * y, 0.3 + 0.3 * x * y], -1)
    stored = (stored * 255).round().astype(np.uint8)
    picture = Image.fromarray(stored)
    picture.info["icc_profile"] = wide_profile()
    pillow_heif.from_pillow(picture).save(tmp_path / "wide.heic", quality=95, chroma=444)
    image = read_image(tmp_path / "wide.heic", dtype=torch.float64)[0].permute(1, 2, 0).numpy()
    want = p3_to_srgb(stored.astype(np.float64))
    assert np.abs(image - want).mean() < 2 / 255
    assert np.abs(image - stored / 255.0).mean() > 5 / 255


def test_a_profile_named_after_srgb_that_is_not_srgb_is_applied(tmp_path, gen):
    """sRGB's primaries with a linear curve, named "sRGB linear (g10)" as such profiles are: not sRGB's values, so
    converted (a check by name alone would have taken it for sRGB)."""
    stored = _pixels(gen)
    linear = wide_profile(SRGB_D50, 1.0, b"sRGB linear (g10)")
    Image.fromarray(stored).save(tmp_path / "linear.png", icc_profile=linear)
    image = read_image(tmp_path / "linear.png", dtype=torch.float64)[0].permute(1, 2, 0).numpy()
    s = stored / 255.0  # linear light: sRGB's curve makes its values
    want = np.where(s <= 0.0031308, 12.92 * s, 1.055 * s ** (1 / 2.4) - 0.055)
    assert np.abs(image - want).max() < 1.5 / 255
    assert np.abs(stored / 255.0 - want).max() > 20 / 255
