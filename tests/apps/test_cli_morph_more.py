"""The morph CLI for #22 (no point files: --match, --face-index, --save-points) and #23 (sequences, average,
timing, regions and backgrounds, --frame, --report, RGBA outputs)."""

import json
import math
import re
import sys

import imageio.v3 as iio
import numpy as np
import pytest
import torch
import torch.nn.functional as F

from torchfluidwarp.apps.cli import main
from torchfluidwarp.data import load_sample, load_sample_points
from torchfluidwarp.io import read_image, read_points, write_image, write_points

FAST = ["--grid", "12", "--steps", "3", "--max-iter", "5", "--quiet"]


def affine_copy(image, points, angle, scale, shift):
    """``image`` (1, C, H, W) under ``p -> R(angle) scale (p - c) + c + shift`` (pixels), and ``points`` moved so."""
    H, W = image.shape[-2:]
    c = torch.tensor([(W - 1) / 2, (H - 1) / 2], dtype=torch.float64)
    a = math.radians(angle)
    m = scale * torch.tensor([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]], dtype=torch.float64)
    ys, xs = torch.meshgrid(torch.arange(H, dtype=torch.float64), torch.arange(W, dtype=torch.float64), indexing="ij")
    src = (torch.stack([xs, ys], -1) - c - torch.tensor(shift, dtype=torch.float64)) @ torch.linalg.inv(m).T + c
    grid = torch.stack([(src[..., 0] + 0.5) / W * 2 - 1, (src[..., 1] + 0.5) / H * 2 - 1], -1)
    warped = F.grid_sample(image, grid[None].float(), padding_mode="border", align_corners=False)
    moved = (points.double() - c) @ m.T + c + torch.tensor(shift, dtype=torch.float64)
    return warped, moved.float()


@pytest.fixture(scope="module")
def astronauts(tmp_path_factory):
    """The astronaut at 128 px and a copy under a known mild affine map, written as PNGs, with their points."""
    folder = tmp_path_factory.mktemp("astronauts")
    a = F.interpolate(load_sample("astronaut"), size=(128, 128), mode="bilinear", antialias=True)
    pa = (load_sample_points("astronaut") + 0.5) / 4 - 0.5
    b, pb = affine_copy(a, pa, 4.0, 0.95, (3.0, -2.0))
    paths = folder / "a.png", folder / "b.png"
    write_image(paths[0], a[0])
    write_image(paths[1], b[0])
    files = folder / "a.pts", folder / "b.pts"
    write_points(files[0], pa)
    write_points(files[1], pb)
    return paths, files, (a, b), (pa, pb)


def test_features_morph_needs_no_point_files_and_saves_the_points(astronauts, tmp_path, capsys):
    (a, b), _, (image_a, image_b), _ = astronauts
    out, sa, sb = tmp_path / "m.gif", tmp_path / "a.json", tmp_path / "b.csv"
    argv = ["morph", str(a), str(b), "-o", str(out), "--frames", "3", "--match", "features", *FAST]
    assert main([*argv, "--save-points", str(sa), str(sb)]) == 0
    assert iio.imread(out, index=None).shape == (3, 128, 128, 3)
    pa, pb = read_points(sa), read_points(sb)
    assert pa.shape == pb.shape and pa.shape[0] >= 3 + 8  # matches and the 8 border points
    # the matches follow the known map: B's point is A's point carried by it (within SIFT's accuracy)
    c, m = (
        torch.tensor([63.5, 63.5]),
        0.95
        * torch.tensor(
            [
                [math.cos(math.radians(4)), -math.sin(math.radians(4))],
                [math.sin(math.radians(4)), math.cos(math.radians(4))],
            ]
        ),
    )
    inner = (pa[:, 0] > 8) & (pa[:, 0] < 119) & (pa[:, 1] > 8) & (pa[:, 1] < 119)  # not the border points
    moved = (pa[inner] - c) @ m.T + c + torch.tensor([3.0, -2.0])
    assert (moved - pb[inner]).norm(dim=1).median() < 1.5
    # rerun with the saved points, as a user who corrected them would
    again = ["morph", str(a), str(b), "--points-a", str(sa), "--points-b", str(sb), "-o", str(tmp_path / "n.gif")]
    assert main([*again, "--frames", "3", *FAST]) == 0


def test_faces_morph_finds_the_landmarks(astronauts, tmp_path):
    (a, b), _, _, (pa_marked, _) = astronauts
    sa, sb = tmp_path / "a.pts", tmp_path / "b.pts"
    argv = ["morph", str(a), str(b), "-o", str(tmp_path / "f.gif"), "--frames", "2", "--match", "faces"]
    assert main([*argv, "--face-index", "0", "--save-points", str(sa), str(sb), *FAST]) == 0
    pa = read_points(sa)
    assert pa.shape[0] > 40  # the face landmarks and the border points
    # the face landmarks lie on the face: within the hand-marked points' box, grown a little
    lo, hi = pa_marked.min(0).values - 10, pa_marked.max(0).values + 10
    inner = pa[(pa[:, 0] > 4) & (pa[:, 0] < 123) & (pa[:, 1] > 4) & (pa[:, 1] < 123)]
    assert ((inner >= lo) & (inner <= hi)).all(dim=1).float().mean() > 0.9


def test_face_index_picks_a_face_in_a_or_each_photo_that_shows_several(tmp_path, capsys):
    # a group photo (the astronaut's head large on the left, small on the right) and a portrait: --face-index 1
    # takes the small face and keeps the portrait's only one; --face-index 1,0 says the same for A and B, and may
    # stand before the image files
    crop = load_sample("astronaut")[..., 0:256, 96:352]
    group = torch.full((1, 3, 256, 512), 0.5)
    group[..., :, :256] = crop
    group[..., 48:208, 304:464] = F.interpolate(crop, size=(160, 160), mode="bilinear", antialias=True)
    write_image(tmp_path / "group.png", group[0])
    write_image(tmp_path / "one.png", crop[0])
    images = [str(tmp_path / "group.png"), str(tmp_path / "one.png")]
    for n, options in enumerate((["--face-index", "1"], ["--face-index", "1,0"])):
        saved = tmp_path / f"a{n}.pts", tmp_path / f"b{n}.pts"
        out = ["-o", str(tmp_path / f"m{n}.gif"), "--save-points", *map(str, saved), "--frames", "2"]
        argv = ["morph", *options, *images, "--match", "faces"] if n else ["morph", *images, *options]
        assert main([*argv, *out, *FAST]) == 0
        pa, pb = read_points(saved[0]), read_points(saved[1])
        inner = (pa[:, 0] > 4) & (pa[:, 0] < 507) & (pa[:, 1] > 4) & (pa[:, 1] < 251)  # not the border points
        assert pa[inner, 0].min() > 290  # the small face, on the right
        assert (pb[inner] - pb[inner].mean(0)).norm(dim=1).max() < 128  # the portrait's face
    capsys.readouterr()
    out = ["-o", str(tmp_path / "x.gif"), *FAST]
    assert main(["morph", *images, "--face-index", "1,1", *out]) == 2
    assert "face_index=1, but " in (err := capsys.readouterr().err) and "one.png has 1 face(s)" in err
    assert main(["morph", *images, "--face-index", "1,0,2", *out]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "expected I or I,J" in err
    # a morph through three photos takes one index (the face of each photo that shows several), not a pair
    seq = ["morph", images[1], images[0], images[1], "--frames", "3"]
    assert main([*seq, "-o", str(tmp_path / "s.gif"), "--face-index", "1", *FAST]) == 0
    assert main([*seq, "-o", str(tmp_path / "t.gif"), "--face-index", "1,0", *FAST]) == 2
    assert "a morph through 3 takes one index" in capsys.readouterr().err


def test_missing_faces_extra_is_a_one_line_install_hint(astronauts, tmp_path, capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "mediapipe", None)  # import mediapipe now raises ImportError
    (a, b), _, _, _ = astronauts
    out = tmp_path / "f.gif"
    assert main(["morph", str(a), str(b), "-o", str(out), "--match", "faces", *FAST]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and 'pip install "torchfluidwarp[faces]"' in err
    assert not out.exists()


def test_no_face_names_the_file(tmp_path, capsys):
    blank = tmp_path / "blank.png"
    write_image(blank, torch.full((3, 64, 64), 0.5))
    assert main(["morph", str(blank), str(blank), "-o", str(tmp_path / "x.gif"), "--match", "faces", *FAST]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "blank.png" in err


def test_points_outside_their_picture_are_named_by_their_file_with_the_likely_cause(astronauts, tmp_path, capsys):
    (a, b), files, _, (pa, pb) = astronauts
    wide = tmp_path / "narrow.png"  # a narrow B, 40 px wide
    write_image(wide, torch.full((3, 128, 40), 0.5))
    shifted = tmp_path / "one_based.pts"
    write_points(shifted, pb.clamp(0, 39) + 1.0)  # inside 40 x 128 once 1 is subtracted; some beyond x = 39.5
    code = main(["morph", str(a), str(wide), "--points", str(files[0]), str(shifted), "-o", str(tmp_path / "x.gif")])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1, err
    assert "points file '" in err and "one_based.pts' has a point outside the 40 x 128 image" in err, err
    assert "--points-a" not in err and "--points-b" not in err and "1-based (subtract 1)" in err, err


def test_a_morph_that_meets_none_of_the_marks_writes_nothing_and_says_why(astronauts, tmp_path, capsys):
    (a, _), files, _, _ = astronauts
    cat = tmp_path / "cat.png"
    write_image(cat, F.interpolate(load_sample("cat"), size=(128, 128), mode="bilinear", antialias=True)[0])
    swapped = tmp_path / "yx.pts"  # the cat's points as (y, x) pairs
    write_points(swapped, ((load_sample_points("cat") + 0.5) / 4 - 0.5).flip(-1))
    out = tmp_path / "m.gif"
    code = main(["morph", str(a), str(cat), "--points", str(files[0]), str(swapped), "-o", str(out), "--frames", "3"])
    err = capsys.readouterr().err
    assert code == 2 and not out.exists(), err
    assert "points_b look mirrored" in err and "error: the morph met none of the 23 marks: each was let go" in err, err


@pytest.fixture
def three(tmp_path):
    gen = torch.Generator().manual_seed(3)
    paths, files = [], []
    base = torch.tensor([[10.0, 10.0], [30.0, 12.0], [20.0, 28.0], [8.0, 26.0]])
    for k in range(3):
        paths.append(tmp_path / f"i{k}.png")
        write_image(paths[-1], torch.rand(3, 36, 40, generator=gen))
        files.append(tmp_path / f"i{k}.pts")
        write_points(files[-1], base + torch.tensor([2.0 * k, 1.0 * k]))
    return [str(p) for p in paths], [str(f) for f in files]


def test_a_sequences_point_files_are_checked_against_their_pictures_by_name(three, tmp_path, capsys):
    images, files = three
    write_points(files[2], read_points(files[2]) / torch.tensor([40.0, 36.0]))  # normalised coordinates
    assert main(["morph", *images, "--points", *files, "-o", str(tmp_path / "s.gif")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"points file {files[2]!r}: all 4 points lie within [0, 1]" in err, err
    assert "multiply by (40, 36)" in err and "argument --points" not in err, err


def test_sequence_of_three_images_writes_one_animation_and_reports_each_segment(three, tmp_path):
    images, files = three
    out, report = tmp_path / "seq.gif", tmp_path / "r.json"
    argv = ["morph", *images, "--points", *files, "-o", str(out), "--frames", "7", "--report", str(report), *FAST]
    assert main(argv) == 0
    frames = iio.imread(out, index=None)
    assert frames.shape == (7, 36, 40, 3)
    first = iio.imread(images[0])
    assert np.abs(frames[0].astype(int) - first.astype(int)).mean() < 12  # frame 0 is image 0, in a GIF's palette
    segments = json.loads(report.read_text())["segments"]
    assert len(segments) == 2 and all(s["folds"]["total"] == 0 for s in segments)


def test_a_sequence_report_renders_each_frame_once_and_writes_the_same_animation(three, tmp_path, rendered):
    images, files = three
    argv = ["morph", *images, "--points", *files, "--frames", "7", *FAST]
    assert main([*argv, "-o", str(tmp_path / "plain.gif")]) == 0
    once = sum(rendered)  # each segment renders its own frames, the joint in both
    rendered.clear()
    report = tmp_path / "r.json"
    assert main([*argv, "-o", str(tmp_path / "reported.gif"), "--report", str(report)]) == 0
    assert sum(rendered) == once  # the reports' passes wrote the animation: no second rendering
    plain, reported = iio.imread(tmp_path / "plain.gif", index=None), iio.imread(tmp_path / "reported.gif", index=None)
    assert plain.shape == reported.shape == (7, 36, 40, 3) and (plain == reported).all()
    segments = json.loads(report.read_text())["segments"]
    assert sum(s["frames"] for s in segments) == 7 + 1  # the joint is measured in both segments


def test_a_sequence_animation_is_shrunk_to_max_size_as_a_morph_is(three, tmp_path, capsys):
    images, files = three  # 40 x 36 pictures
    out = tmp_path / "small.gif"
    assert main(["morph", *images, "--points", *files, "-o", str(out), "--frames", "4", "--max-size", "20", *FAST]) == 0
    assert iio.imread(out, index=None).shape[:3] == (4, 18, 20)
    assert (
        main(
            [
                "morph",
                *images,
                "--points",
                *files,
                "-o",
                str(tmp_path / "s.gif"),
                "--frames",
                "4",
                "--max-size",
                "20",
                *FAST[:-1],
            ]
        )
        == 0
    )
    assert "frames written at 20 x 18 px: the first image's 40 x 36 shrunk to --max-size 20" in capsys.readouterr().err


def test_sequence_frame_at_one_is_the_last_image(three, tmp_path):
    images, files = three
    out = tmp_path / "end.png"
    assert main(["morph", *images, "--points", *files, "--frame", "1", "-o", str(out), *FAST]) == 0
    assert np.abs(iio.imread(out).astype(int) - iio.imread(images[2]).astype(int)).max() <= 1


def test_a_sequence_needs_one_point_file_per_image(three, tmp_path, capsys):
    images, files = three
    assert main(["morph", *images, "--points", *files[:2], "-o", str(tmp_path / "s.gif"), *FAST]) == 2
    assert "one file per image: 3 images, 2" in capsys.readouterr().err
    # without point files a sequence looks for each image's face: these noise pictures show none
    assert main(["morph", *images, "-o", str(tmp_path / "s.gif"), *FAST]) == 2
    assert f"no face found in {images[0]}" in capsys.readouterr().err
    assert main(["morph", *images, "--match", "features", "-o", str(tmp_path / "s.gif"), *FAST]) == 2
    assert "--match features finds the points of two images only" in capsys.readouterr().err


def test_average_of_one_image_repeated_is_that_image(three, tmp_path):
    images, files = three
    out, mean = tmp_path / "mean.png", tmp_path / "mean.pts"
    argv = ["average", images[0], images[0], "--points", files[0], files[0], "-o", str(out)]
    assert main([*argv, "--save-points", str(mean), "--grid", "12", "--steps", "3", "--max-iter", "5", "-q"]) == 0
    assert np.abs(iio.imread(out).astype(int) - iio.imread(images[0]).astype(int)).max() <= 2
    assert torch.allclose(read_points(mean), read_points(files[0]), atol=1e-3)


def test_middle_frame_report_and_held_out_points(astronauts, tmp_path):
    (a, b), (fa, fb), _, (pa, pb) = astronauts
    keep, held = slice(0, 18), slice(18, None)
    files = []
    for name, p in (("ka.pts", pa[keep]), ("kb.pts", pb[keep]), ("ha.pts", pa[held]), ("hb.pts", pb[held])):
        files.append(str(write_points(tmp_path / name, p)))
    out, report = tmp_path / "mid.png", tmp_path / "report.json"
    argv = ["morph", str(a), str(b), "--points", *files[:2], "--frame", "0.5", "-o", str(out)]
    argv += ["--report", str(report), "--held-out-a", files[2], "--held-out-b", files[3], "--frames", "5", *FAST]
    assert main(argv) == 0
    assert read_image(out).shape == (1, 3, 128, 128)
    data = json.loads(report.read_text())
    assert data["frames"] == 5 and data["held_out"]["end"]["of"] == 5
    assert data["landmark_error_px"]["mean"] < 3 and len(data["folds"]["a"]) == 5


def test_held_out_without_report_is_refused(astronauts, tmp_path, capsys):
    (a, b), (fa, fb), _, _ = astronauts
    argv = ["morph", str(a), str(b), "--points", str(fa), str(fb), "-o", str(tmp_path / "m.gif")]
    assert main([*argv, "--held-out-a", str(fa), "--held-out-b", str(fb), *FAST]) == 2
    assert "add --report" in capsys.readouterr().err


@pytest.mark.parametrize("bad", ["fast", "0:0,0.5:1.2,1:1", "0:0,x:1"])
def test_bad_schedules_are_argparse_errors(bad, astronauts, tmp_path, capsys):
    (a, b), (fa, fb), _, _ = astronauts
    assert main(["morph", str(a), str(b), "--points", str(fa), str(fb), "--motion", bad]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--motion" in err


def test_region_keeps_the_background_outside_and_schedules_apply(astronauts, tmp_path):
    (a, b), (fa, fb), (image_a, _), (pa, _) = astronauts
    out = tmp_path / "mid.png"
    argv = ["morph", str(a), str(b), "--points", str(fa), str(fb), "--frame", "0.5", "-o", str(out), *FAST]
    argv += ["--region", "points", "--region-margin", "0.1", "--background", "a", "--motion", "0:0,0.3:0.7,1:1"]
    assert main([*argv, "--blend", "ease-in"]) == 0
    got, want = iio.imread(out).astype(int), iio.imread(a).astype(int)
    lo, hi = (pa.min(0).values - 30).long(), (pa.max(0).values + 30).long()
    outside = np.ones((128, 128), bool)
    outside[max(0, int(lo[1])) : int(hi[1]), max(0, int(lo[0])) : int(hi[0])] = False
    assert outside.sum() > 1000 and np.abs(got - want)[outside].max() <= 1


def test_region_masks_and_a_transparent_gif(tmp_path):
    gen = torch.Generator().manual_seed(1)
    ys, xs = torch.meshgrid(torch.arange(40), torch.arange(40), indexing="ij")
    disc = (((xs - 20.0) ** 2 + (ys - 20.0) ** 2) < 144).float()
    paths = []
    for k in range(2):
        paths.append(
            str(write_image(tmp_path / f"r{k}.png", torch.cat([torch.rand(3, 40, 40, generator=gen), disc[None]])))
        )
    mask = str(write_image(tmp_path / "mask.png", disc[None]))
    points = [
        str(write_points(tmp_path / f"p{k}.pts", torch.tensor([[14.0, 14.0], [26.0, 14.0], [20.0, 27.0 - k]])))
        for k in range(2)
    ]
    out = tmp_path / "t.gif"
    argv = ["morph", *paths, "--points", *points, "-o", str(out), "--frames", "3", "--region", f"{mask},{mask}", *FAST]
    assert main(argv) == 0
    frames = iio.imread(out, index=None, mode="RGBA")
    assert frames.shape == (3, 40, 40, 4)
    corner = np.zeros((40, 40), bool)
    corner[:4, :4] = corner[-4:, -4:] = True  # far outside the disc: transparent in A, B and every frame
    assert np.all(frames[:, corner, 3] == 0) and np.all(frames[:, 18:22, 18:22, 3] == 255)
    webp = tmp_path / "t.webp"
    argv = ["morph", *paths, "--points", *points, "-o", str(webp), "--frames", "3", *FAST]
    assert main(argv) == 0
    assert webp.read_bytes()[8:12] == b"WEBP"


def test_points_the_command_line_found_reach_the_morph_as_found(astronauts, tmp_path, monkeypatch):
    # the command line finds the points itself (to say which matcher it used); the morph must still know they were
    # found, so that matched features only start the pixels' alignment, as morph(match=...) takes them, and the
    # report measures the marks against where the morph aimed them
    from torchfluidwarp.morph import morph as real_morph

    (a, b), _, _, _ = astronauts
    seen = []

    def spy(*args, **kwargs):
        seen.append((args[2:], kwargs.get("placed")))
        result = real_morph(*args, **kwargs)
        seen.append(result)
        return result

    monkeypatch.setattr("torchfluidwarp.apps.cli_morph.morph", spy)
    report = tmp_path / "r.json"
    argv = ["morph", str(a), str(b), "-o", str(tmp_path / "m.gif"), "--frames", "2", "--match", "features"]
    assert main([*argv, "--report", str(report), *FAST]) == 0
    (given, placed), result = seen
    assert given == (None, None) and placed is not None and placed.matcher == "features"
    marked = json.loads(report.read_text())["marked"]["end"]["mean"]  # read off the last frame's map
    assert marked == pytest.approx(float(result.error.mean()), abs=0.25)


def test_an_existing_output_is_refused_before_the_points_are_searched_for(astronauts, tmp_path, capsys, monkeypatch):
    (a, b), _, _, _ = astronauts
    calls = []
    monkeypatch.setattr("torchfluidwarp.apps.cli_morph.find_points", lambda *x, **k: calls.append(1))
    out = tmp_path / "exists.gif"
    out.write_bytes(b"keep me")
    assert main(["morph", str(a), str(b), "-o", str(out), *FAST]) == 2
    assert "already exists" in capsys.readouterr().err and calls == [] and out.read_bytes() == b"keep me"
    assert main(["morph", str(a), str(b), "--frame", "0.5", "-o", str(tmp_path / "mid.xyz"), *FAST]) == 2
    assert "an image needs a suffix" in capsys.readouterr().err and calls == []


def test_average_and_sequence_of_faces_need_no_point_files(astronauts, tmp_path, capsys):
    # without --points each image's face landmarks are found: the same result as those landmarks given as files
    pytest.importorskip("mediapipe")
    from torchfluidwarp.correspond import detect_face_points

    (a, b), _, _, _ = astronauts
    marks = [detect_face_points(read_image(path)) for path in (a, b)]  # the pictures as the command reads them
    files = [str(write_points(tmp_path / f"{n}.pts", m)) for n, m in zip("ab", marks)]
    found, given = tmp_path / "found.png", tmp_path / "given.png"
    settings = ["--grid", "12", "--steps", "3", "--max-iter", "5"]
    assert main(["average", str(a), str(b), "-o", str(found), *settings]) == 0
    err = capsys.readouterr().err
    assert "average: found the face landmarks (63 points) of each of the 2 pictures" in err
    assert re.search(r"average: 2 images, mean point error [\d.]+ px, folded fraction \S+, [\d.]+ s \(", err), err
    # a sequence: the note of the points comes before what the morphs warned of after them (the paper's fit for
    # 2 iterations: its marks far off)
    again = ["morph", str(a), str(b), str(a), "-o", str(tmp_path / "again.gif"), "--frames", "3"]
    assert main([*again, "--method", "paper", "--max-iter", "2", "--grid", "12", "--steps", "3"]) == 0
    err = capsys.readouterr().err
    assert err.index("found the face landmarks") < err.index("warning: the marks end") < err.index("2 segments"), err
    assert main(["average", str(a), str(b), "--points", *files, "-o", str(given), *settings, "-q"]) == 0
    assert np.abs(iio.imread(found).astype(int) - iio.imread(given).astype(int)).max() <= 1
    seq = tmp_path / "seq.gif"
    assert main(["morph", str(a), str(b), str(a), "-o", str(seq), "--frames", "5", *FAST[:-1]]) == 0
    said = capsys.readouterr().err
    assert "morph: found the face landmarks (63 points) of each of the 3 pictures" in said
    assert "morph: 2 segments, mean point error per segment" in said
    frames = iio.imread(seq, index=None)
    assert frames.shape == (5, 128, 128, 3)  # through B and back to A: the last frame is A again
    assert np.abs(frames[-1].astype(int) - iio.imread(a).astype(int)).mean() < 3  # GIF palette, not the morph


def test_average_without_the_faces_extra_says_how_to_get_it(astronauts, tmp_path, capsys, monkeypatch):
    (a, b), _, _, _ = astronauts
    monkeypatch.setitem(sys.modules, "mediapipe", None)  # import mediapipe now raises ImportError
    assert main(["average", str(a), str(b), "-o", str(tmp_path / "m.png")]) == 2  # the user's to fix: not a bug
    assert "torchfluidwarp[faces]" in capsys.readouterr().err
