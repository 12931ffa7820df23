import json

import imageio.v3 as iio
import pytest
import torch

from torchfluidwarp.apps.cli import main
from torchfluidwarp.io import write_image, write_points

FAST = ["--grid", "16", "--steps", "3", "--max-iter", "10", "--quiet"]  # --control is --method paper's


@pytest.fixture
def pair(tmp_path, gen):
    a, b = tmp_path / "a.png", tmp_path / "b.png"
    write_image(a, torch.rand(3, 40, 48, generator=gen))
    write_image(b, torch.rand(3, 50, 60, generator=gen))
    pa, pb = tmp_path / "a.pts", tmp_path / "b.json"
    write_points(pa, torch.tensor([[10.0, 10.0], [30.0, 12.0], [20.0, 30.0]]))
    write_points(pb, torch.tensor([[14.0, 12.0], [40.0, 15.0], [25.0, 40.0]]))
    return a, b, pa, pb


def test_morph_writes_the_expected_frames(pair, tmp_path):
    a, b, pa, pb = pair
    out = tmp_path / "m.gif"
    assert (
        main(
            [
                "morph",
                str(a),
                str(b),
                "--points-a",
                str(pa),
                "--points-b",
                str(pb),
                "-o",
                str(out),
                "--frames",
                "5",
                *FAST,
            ]
        )
        == 0
    )
    frames = iio.imread(out, index=None)
    assert frames.shape[0] == 5 and frames.shape[1:3] == (40, 48)


def test_morph_bad_inputs_exit_2(pair, tmp_path, capsys):
    a, b, pa, pb = pair
    out = str(tmp_path / "m.gif")
    assert (
        main(
            [
                "morph",
                str(tmp_path / "missing.png"),
                str(b),
                "--points-a",
                str(pa),
                "--points-b",
                str(pb),
                "-o",
                out,
                *FAST,
            ]
        )
        == 2
    )
    bad = tmp_path / "bad.csv"
    write_points(bad, torch.tensor([[1.0, 2.0]]))
    assert main(["morph", str(a), str(b), "--points-a", str(pa), "--points-b", str(bad), "-o", out, *FAST]) == 2
    err = capsys.readouterr().err
    assert "--points-a has 3 points but --points-b has 1" in err
    assert len([line for line in err.splitlines() if "error" in line]) == 2


def test_demo_writes_a_gif_and_refuses_to_overwrite(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert main(["demo", "--frames", "4", *FAST]) == 0
    frames = iio.imread(tmp_path / "morph.gif", index=None)
    assert frames.shape[0] == 4 and frames.shape[1:3] == (512, 512)
    assert main(["demo", "--frames", "4", *FAST]) == 2


def test_the_options_build_the_methods_typed_settings():
    from torchfluidwarp.apps.cli import build_parser
    from torchfluidwarp.apps.cli_morph_output import morph_settings, result_options
    from torchfluidwarp.morph import Blending, NaturalSettings, PaperSettings, Timing

    parser = build_parser()
    args = parser.parse_args(["morph", "a.png", "b.png", "--straightness", "2", "--align", "none"])
    assert morph_settings(args) == NaturalSettings(straightness=2.0, align=None)
    args = parser.parse_args(["morph", "a.png", "b.png", "--method", "paper", "--smoothness", "1", "--control", "3"])
    assert morph_settings(args) == PaperSettings(smoothness=1.0, control=(3, 3))
    args = parser.parse_args(["morph", "a.png", "b.png", "--motion", "ease-out", "--region", "points"])
    timing, blending = result_options(args)
    assert timing == Timing(motion="ease-out") and isinstance(blending, Blending) and blending.region == "points"


@pytest.mark.parametrize(
    "options, message",
    [
        (["--smoothness", "2"], "--smoothness applies to --method paper, not --method natural"),
        (["--control", "4"], "--control applies to --method paper, not --method natural"),
        (
            ["--method", "paper", "--straightness", "2"],
            "--straightness applies to --method natural, not --method paper",
        ),
    ],
)
def test_an_option_of_the_other_method_exits_2_naming_it(pair, tmp_path, capsys, options, message):
    a, b, pa, pb = pair
    argv = ["morph", str(a), str(b), "--points-a", str(pa), "--points-b", str(pb), "-o", str(tmp_path / "m.gif")]
    assert main([*argv, *options, "--quiet"]) == 2
    assert message in capsys.readouterr().err


def test_the_printed_time_is_the_runs_wall_time_and_its_parts_add_up_to_it(pair, tmp_path, capsys, monkeypatch):
    import re
    import time

    from torchfluidwarp.apps import cli_morph

    a, b, pa, pb = pair
    written = cli_morph.write_result

    def slow_write(result, args):  # the frames are rendered as the file is written: make that part long
        time.sleep(0.6)
        return written(result, args)

    monkeypatch.setattr(cli_morph, "write_result", slow_write)
    args = ["morph", str(a), str(b), "--points-a", str(pa), "--points-b", str(pb), "-o", str(tmp_path / "m.gif")]
    begin = time.perf_counter()
    assert main([*args, "--frames", "3", *[f for f in FAST if f != "--quiet"]]) == 0
    wall = time.perf_counter() - begin
    err = capsys.readouterr().err
    found = re.search(r"mean point error [0-9.]+ px \(max [0-9.]+\), ([0-9.]+) s \((.*)\)$", err.strip())
    assert found, err  # CI greps the line up to the total
    total = float(found.group(1))
    parts = dict(re.fullmatch(r"(.+) ([0-9.]+) s", part).groups() for part in found.group(2).split(", "))
    assert list(parts) == ["start", "load", "points", "fit", "render and write"]
    assert float(parts["render and write"]) >= 0.55  # the write's 0.6 s is its own part, not the fit's
    assert abs(sum(map(float, parts.values())) - total) <= 0.1 * total + 0.1  # printed to 0.1 s each
    assert 0.9 * wall - 0.05 <= total <= wall + 0.05  # the whole run, not a part of it


def test_the_automatic_mode_says_which_matcher_it_used_in_the_command_lines_words(tmp_path, capsys):
    from torchfluidwarp.data import load_sample

    cat = load_sample("cat")[0]  # no face the face model knows: the automatic mode falls back to features
    a, b = tmp_path / "a.png", tmp_path / "b.png"
    write_image(a, cat)
    write_image(b, cat[:, 8:, 4:])
    out = tmp_path / "m.gif"
    assert main(["morph", str(a), str(b), "-o", str(out), "--frames", "3", *[f for f in FAST if f != "--quiet"]]) == 0
    err = capsys.readouterr().err
    assert f"no face found in {a}" in err and "matched image features instead" in err
    assert "use --match features to skip the face search" in err and "match='" not in err


def test_a_report_renders_each_frame_once_and_writes_the_same_animation(pair, tmp_path, rendered):
    a, b, pa, pb = pair
    args = ["morph", str(a), str(b), "--points-a", str(pa), "--points-b", str(pb), "--frames", "5", *FAST]
    assert main([*args, "-o", str(tmp_path / "plain.gif")]) == 0
    assert sum(rendered) == 5
    rendered.clear()
    assert main([*args, "-o", str(tmp_path / "reported.gif"), "--report", str(tmp_path / "r.json")]) == 0
    assert sum(rendered) == 5  # the report's pass wrote the animation: not 10
    plain = iio.imread(tmp_path / "plain.gif", index=None)
    reported = iio.imread(tmp_path / "reported.gif", index=None)
    assert plain.shape == reported.shape and (plain == reported).all()
    assert len(json.loads((tmp_path / "r.json").read_text())["path"]["distances"]) == 4


def test_size_sets_the_frames_size_and_is_checked(pair, tmp_path, capsys):
    a, b, pa, pb = pair
    base = ["morph", str(a), str(b), "--points-a", str(pa), "--points-b", str(pb), "--frames", "3", *FAST]
    out = tmp_path / "s.gif"
    assert main([*base, "-o", str(out), "--size", "24", "36"]) == 0
    assert iio.imread(out, index=None).shape[:3] == (3, 24, 36)  # H W
    square = tmp_path / "q.gif"
    assert main([*base, "-o", str(square), "--size", "30"]) == 0
    assert iio.imread(square, index=None).shape[:3] == (3, 30, 30)
    capsys.readouterr()
    assert main([*base, "-o", str(tmp_path / "bad.gif"), "--size", "1", "2", "3"]) == 2
    assert "--size takes 1 or 2 integers" in capsys.readouterr().err
    # the work is estimated at the output's size, before any: 100 frames of 20000 x 20000 are refused at once
    assert main([*base, "-o", str(tmp_path / "big.gif"), "--size", "20000", "--frames", "100"]) == 2
    err = capsys.readouterr().err
    assert "20000" in err and "--max-minutes" in err
    assert not (tmp_path / "big.gif").exists()


def test_max_size_shrinks_an_animation_of_a_larger_first_image_and_says_so(pair, tmp_path, capsys):
    # A is 48 x 40: with --max-size 24 its animations are written at 24 x 20 (one factor, rounded), with a note that
    # names the way back; --size, --max-size 0, a folder of PNG frames and --frame's image keep their sizes
    a, b, pa, pb = pair
    base = ["morph", str(a), str(b), "--points-a", str(pa), "--points-b", str(pb), "--frames", "3", *FAST[:-1]]
    for name in ("s.gif", "s.webp"):
        assert main([*base, "-o", str(tmp_path / name), "--max-size", "24"]) == 0
        assert iio.imread(tmp_path / name, index=0).shape[:2] == (20, 24)
        err = capsys.readouterr().err
        assert "frames written at 24 x 20 px: the first image's 48 x 40 shrunk to --max-size 24" in err
        assert err.count("--size 40 48 (or --max-size 0) writes them at its size") == 1
    kept = {
        "sized.gif": ["--max-size", "24", "--size", "30", "36"],
        "whole.gif": ["--max-size", "0"],
        "fits.gif": ["--max-size", "48"],  # the longer side is already within it
        "frames/": ["--max-size", "24"],
    }
    for name, options in kept.items():
        assert main([*base, "-o", str(tmp_path / name), *options]) == 0
        assert "shrunk" not in capsys.readouterr().err
    assert iio.imread(tmp_path / "sized.gif", index=None).shape[1:3] == (30, 36)
    assert iio.imread(tmp_path / "whole.gif", index=None).shape[1:3] == (40, 48)
    assert iio.imread(tmp_path / "fits.gif", index=None).shape[1:3] == (40, 48)
    assert iio.imread(tmp_path / "frames" / "frame_0000.png").shape[:2] == (40, 48)
    assert main([*base, "--frame", "0.5", "-o", str(tmp_path / "mid.png"), "--max-size", "24"]) == 0
    assert iio.imread(tmp_path / "mid.png").shape[:2] == (40, 48)
    assert "shrunk" not in capsys.readouterr().err
    report = tmp_path / "r.json"  # the report measures the shrunk frames
    assert main([*base, "-o", str(tmp_path / "r.gif"), "--max-size", "24", "--report", str(report)]) == 0
    assert json.loads(report.read_text())["size"] == [20, 24]
    capsys.readouterr()
    assert main([*base, "-o", str(tmp_path / "r.gif"), "--max-size", "24"]) == 2  # exists: refused, no note first
    assert "shrunk" not in capsys.readouterr().err
    assert main(["demo", "-o", str(tmp_path / "demo.gif"), "--frames", "2", "--max-size", "128", *FAST[:-1]]) == 0
    assert "the first image's 512 x 512 shrunk to --max-size 128" in capsys.readouterr().err
    assert iio.imread(tmp_path / "demo.gif", index=0).shape[:2] == (128, 128)
    assert main([*base, "-o", str(tmp_path / "quiet.gif"), "--max-size", "24", "--quiet"]) == 0
    assert capsys.readouterr().err == ""  # --quiet says nothing, and still shrinks
    assert iio.imread(tmp_path / "quiet.gif", index=None).shape[1:3] == (20, 24)
