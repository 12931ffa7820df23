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


def _xyz(v) -> bytes:
    return b"XYZ " + bytes(4) + b"".join(_s15(c) for c in v)


def _icc(kind: bytes, tags: list[tuple[bytes, bytes]], name: bytes) -> bytes:
    """An ICC v2 profile: its header (``kind``: class, colour space and connection space, 12 bytes), a
    description, a white point (D50), a copyright and ``tags``."""
    name = name + b"\0"
    desc = b"desc" + bytes(4) + struct.pack(">I", len(name)) + name + struct.pack(">IIHB", 0, 0, 0, 0) + bytes(67)
    tags = [(b"desc", desc), (b"wtpt", _xyz(D50)), *tags, (b"cprt", b"text" + bytes(4) + b"none\0")]
    start = 128 + 4 + 12 * len(tags)
    table, data = struct.pack(">I", len(tags)), b""
    for sig, body in tags:
        data += bytes(-(start + len(data)) % 4)  # tags start on 4-byte boundaries
        table += sig + struct.pack(">II", start + len(data), len(body))
        data += body
    header = struct.pack(">I", start + len(data)) + b"none" + bytes([2, 0x10, 0, 0]) + kind + bytes(12)
    header += b"acspAPPL" + bytes(24) + b"".join(_s15(c) for c in D50) + b"none" + bytes(44)
    assert len(header) == 128
    return header + table + data


def wide_profile(primaries: np.ndarray = P3_D50, gamma: float = GAMMA, name: bytes = b"wide test RGB") -> bytes:
    """An ICC v2 matrix/TRC RGB display profile, by default with P3's primaries and a plain 2.2 gamma, built here
    (no profile file ships with the test's dependencies)."""
    curve = b"curv" + bytes(4) + struct.pack(">IH", 1, round(gamma * 256))
    tags = [(sig, _xyz(primaries[:, i])) for i, sig in enumerate((b"rXYZ", b"gXYZ", b"bXYZ"))]
    tags += [(b"rTRC", curve), (b"gTRC", curve), (b"bTRC", curve)]
    return _icc(b"mntrRGB XYZ ", tags, name)


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


# A CMYK printing profile, affine in the inks so that LittleCMS's tetrahedral interpolation between the corners
# of its 2-point table is exact: each ink takes this much linear sRGB light away from white paper
INKS = np.array([(0.55, 0.08, 0.04), (0.08, 0.5, 0.08), (0.02, 0.06, 0.5), (0.3, 0.3, 0.3)])  # C, M, Y, K rows


def inks_to_srgb(cmyk: np.ndarray) -> np.ndarray:
    """``(..., 4)`` 8-bit inks (0 = none) -> sRGB in ``[0, 1]`` as the profile below says."""
    linear = (1.0 - (cmyk / 255.0) @ INKS).clip(0, 1)
    return np.where(linear <= 0.0031308, 12.92 * linear, 1.055 * linear ** (1 / 2.4) - 0.055)


def cmyk_profile() -> bytes:
    """An ICC v2 CMYK output profile whose A2B0 is a 16-bit table (``mft2``) with 2 points per ink, to XYZ: white
    paper is the profile connection space's white (LittleCMS forces it so), and every ink is :data:`INKS`."""
    corners = np.array([[(i >> s) & 1 for s in (3, 2, 1, 0)] for i in range(16)], float)  # C varies slowest
    xyz = (1.0 - corners @ INKS) @ SRGB_D50.T  # XYZ (D50) of each corner, 1.0 stored as 0x8000
    identity = struct.pack(">HH", 0, 65535)
    lut = b"mft2" + bytes(4) + bytes([4, 3, 2, 0]) + b"".join(_s15(v) for v in (1, 0, 0, 0, 1, 0, 0, 0, 1))
    lut += struct.pack(">HH", 2, 2) + identity * 4
    lut += b"".join(struct.pack(">H", round(v * 32768)) for v in xyz.reshape(-1)) + identity * 3
    return _icc(b"prtrCMYKXYZ ", [(b"A2B0", lut)], b"test CMYK")


@pytest.mark.parametrize("suffix", [".jpg", ".tif"])
def test_cmyk_inks_are_converted_through_their_profile(tmp_path, gen, suffix):
    """A print shop's CMYK JPEG (or TIFF) carries the profile of its press: its inks are converted through it,
    as Photoshop and colour-managed viewers show them, not by the plain formula R = (1 - C)(1 - K), which is
    up to a hundred levels away here."""
    inks = _pixels(gen, 4)
    path = tmp_path / f"print{suffix}"
    Image.fromarray(inks, "CMYK").save(
        path, icc_profile=cmyk_profile(), **({"quality": 95} if suffix == ".jpg" else {})
    )
    stored = np.asarray(Image.open(path))  # the JPEG's inks as decoded (it is lossy)
    image = read_image(path, dtype=torch.float64)[0].permute(1, 2, 0).numpy()
    want = inks_to_srgb(stored.astype(np.float64))
    assert image.shape == (8, 9, 3)
    assert np.abs(image - want).max() < 1.5 / 255
    plain = np.asarray(Image.open(path).convert("RGB")) / 255.0
    assert np.abs(plain - want).max() > 20 / 255  # the check above could not pass on the plain formula
    np.testing.assert_array_equal(read_image_bytes(path.read_bytes()).numpy(), read_image(path).numpy())


def test_cmyk_without_a_profile_or_with_a_wrong_one_uses_the_plain_formula(tmp_path, gen, recwarn):
    inks = _pixels(gen, 4)
    Image.fromarray(inks, "CMYK").save(tmp_path / "bare.tif")
    plain = torch.from_numpy(np.asarray(Image.fromarray(inks, "CMYK").convert("RGB")).copy()).permute(2, 0, 1)
    torch.testing.assert_close(read_image(tmp_path / "bare.tif")[0], plain.float() / 255, atol=0, rtol=0)
    assert not recwarn.list
    Image.fromarray(inks, "CMYK").save(tmp_path / "wrong.tif", icc_profile=wide_profile())  # an RGB profile
    with pytest.warns(UserWarning, match="wrong.tif' could not be applied .*RGB profile for CMYK.*plain formula"):
        image = read_image(tmp_path / "wrong.tif")
    torch.testing.assert_close(image[0], plain.float() / 255, atol=0, rtol=0)


# linear Display P3 (D65) -> linear sRGB, as published (e.g. in WebKit's and CSS Color 4's conversions)
P3_TO_SRGB = np.array([[1.2249401, -0.2249404, 0.0], [-0.0420569, 1.0420571, 0.0], [-0.0196376, -0.0786361, 1.0982735]])


def _srgb_curve(v: np.ndarray, decode: bool) -> np.ndarray:
    if decode:
        return np.where(v <= 0.04045, v / 12.92, ((v + 0.055) / 1.055) ** 2.4)
    return np.where(v <= 0.0031308, 12.92 * v, 1.055 * v ** (1 / 2.4) - 0.055)


def _nclx_heic(tmp_path, primaries: int, transfer: int) -> tuple[np.ndarray, object]:
    """A smooth picture saved as HEIC tagged with an ``nclx`` box (no ICC profile), as an Android phone tags a
    wide-gamut photograph; its stored pixels as pillow-heif decodes them, unconverted, and the path."""
    pillow_heif = pytest.importorskip("pillow_heif")
    y, x = np.meshgrid(np.linspace(0, 1, 24), np.linspace(0, 1, 40), indexing="ij")
    picture = np.stack([0.15 + 0.8 * x, 0.85 - 0.7 * y, 0.2 + 0.5 * x * y], -1)
    nclx = {"color_primaries": primaries, "transfer_characteristics": transfer, "matrix_coefficients": 6}
    path = tmp_path / "tagged.heic"
    heif = pillow_heif.from_pillow(Image.fromarray((picture * 255).round().astype(np.uint8)))
    heif.save(path, quality=95, chroma=444, nclx_profile={**nclx, "full_range_flag": 1})
    stored = pillow_heif.open_heif(path).to_pillow()
    assert stored.info["nclx_profile"]["color_primaries"] == primaries and "icc_profile" not in stored.info
    return np.asarray(stored.convert("RGB")), path


def test_a_heic_tagged_display_p3_by_its_nclx_box_is_read_in_srgb(tmp_path):
    """The conversion from the box's chromaticities, against the published P3 -> sRGB matrix, to within the
    8-bit rounding; the stored values are tens of levels away."""
    stored, path = _nclx_heic(tmp_path, primaries=12, transfer=13)
    image = read_image(path, dtype=torch.float64)[0].permute(1, 2, 0).numpy()
    linear = _srgb_curve(stored / 255.0, decode=True) @ P3_TO_SRGB.T
    want = _srgb_curve(linear.clip(0, 1), decode=False)
    assert np.abs(image - want).max() < 0.75 / 255
    assert np.abs(stored / 255.0 - want).max() > 20 / 255  # the check above could not pass on the stored values


def test_a_heic_tagged_srgb_or_hdr_by_its_nclx_box_is_read_as_stored(tmp_path, recwarn):
    stored, path = _nclx_heic(tmp_path, primaries=1, transfer=13)  # BT.709 primaries: sRGB's
    np.testing.assert_array_equal((read_image(path)[0].permute(1, 2, 0).numpy() * 255).round(), stored)
    assert not recwarn.list
    (tmp_path / "tagged.heic").unlink()
    stored, path = _nclx_heic(tmp_path, primaries=9, transfer=16)  # BT.2020 with PQ: an HDR picture
    with pytest.warns(UserWarning, match="tagged.heic' are tagged with transfer characteristics 16"):
        image = read_image(path)
    np.testing.assert_array_equal((image[0].permute(1, 2, 0).numpy() * 255).round(), stored)


def test_a_cielab_tiff_is_read_in_srgb_not_as_its_raw_samples(tmp_path):
    """A CIELab TIFF (a scanner's or a print workflow's export) against the colour science in numpy: Lab (D50) to
    XYZ, to linear sRGB through LittleCMS's D50-adapted sRGB matrix, to the sRGB curve; its raw samples, L*, a*
    and b* read as red, green and blue, are far off."""
    tifffile = pytest.importorskip("tifffile")
    y, x = np.meshgrid(np.linspace(0, 1, 16), np.linspace(0, 1, 24), indexing="ij")
    lightness, a_star, b_star = 35 + 50 * x, -25 + 45 * y, 20 - 40 * x * y  # inside sRGB's gamut
    stored = np.stack([np.round(lightness * 255 / 100), np.round(a_star) % 256, np.round(b_star) % 256], -1).astype(
        np.uint8
    )  # L* scaled to a byte, a* and b* as signed bytes
    path = tmp_path / "scan.tif"
    tifffile.imwrite(path, stored, photometric="cielab")
    image = read_image(path, dtype=torch.float64)[0].permute(1, 2, 0).numpy()
    L = stored[..., 0].astype(float) * 100 / 255
    a, b = stored[..., 1].astype(np.int8).astype(float), stored[..., 2].astype(np.int8).astype(float)
    fy = (L + 16) / 116
    f = np.stack([fy + a / 500, fy, fy - b / 200], -1)
    xyz = np.where(f**3 > 216 / 24389, f**3, (116 * f - 16) * 27 / 24389) * np.array(D50)
    linear = xyz @ np.linalg.inv(SRGB_D50).T
    want = _srgb_curve(linear.clip(0, 1), decode=False)
    # LittleCMS interpolates an 8-bit Lab table: within 2.5 levels of 255, within 1 on average
    assert np.abs(image - want).max() < 2.5 / 255 and np.abs(image - want).mean() < 1 / 255
    assert np.abs(stored / 255.0 - want).max() > 0.3  # the raw samples could not pass
