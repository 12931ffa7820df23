"""Batch morphing (``morph --pairs``): resumable, one failure does not stop the others, a summary per pair."""

from __future__ import annotations

import csv
import os
import subprocess
import sys
import time
from pathlib import Path

import imageio.v3 as iio
import numpy as np
import pytest
import torch

from torchfluidwarp.apps import batch
from torchfluidwarp.apps.batch import morph_pairs, planned_work, read_pairs
from torchfluidwarp.apps.cli import main
from torchfluidwarp.apps.cli_args import EXIT_BAD_INPUT, EXIT_OK, work_seconds
from torchfluidwarp.core.grid import SquareCells
from torchfluidwarp.io import write_image, write_points
from torchfluidwarp.morph import NaturalSettings
from torchfluidwarp.morph.result import MorphResult

FAST = ["--grid", "12", "--steps", "2", "--max-iter", "5", "--frames", "4", "--quiet"]
SETTINGS = dict(grid=SquareCells(12 * 12), steps=2, max_iter=5)  # NaturalSettings' fields: "--grid 12"
OPTIONS = dict(settings=NaturalSettings(**SETTINGS), frames=4)
POINTS_A = torch.tensor([[8.0, 8.0], [24.0, 9.0], [15.0, 22.0]])


def make_pairs(folder: Path, gen: torch.Generator, n: int = 3, bad: bool = True) -> Path:
    """``n`` tiny pairs in ``folder/data`` and ``folder/pairs.csv`` (relative paths); with ``bad``, one more row
    whose image B is missing, as row 3."""
    data = folder / "data"
    data.mkdir(parents=True, exist_ok=True)
    rows = ["image_a,image_b,points_a,points_b,name"]
    for k in range(n):
        write_image(data / f"a{k}.png", torch.rand(3, 32, 36, generator=gen))
        write_image(data / f"b{k}.png", torch.rand(3, 32, 36, generator=gen))
        write_points(data / f"a{k}.pts", POINTS_A)
        write_points(data / f"b{k}.json", POINTS_A + torch.tensor([1.0 + k, -1.0]))
        rows.append(f"data/a{k}.png,data/b{k}.png,data/a{k}.pts,data/b{k}.json,pair{k}")
        if bad and k == 0:
            rows.append("data/a0.png,data/missing.png,data/a0.pts,data/b0.json,broken")
    (folder / "pairs.csv").write_text("\n".join(rows) + "\n")
    return folder / "pairs.csv"


def read_csv(path: Path) -> list[dict[str, str]]:
    with open(path, newline="") as fp:
        return list(csv.DictReader(fp))


def listing(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir())


def test_cli_batch_end_to_end_and_resume(tmp_path, gen, capsys, monkeypatch):
    def refuse(self):
        raise AssertionError("the batch streams its frames; it must not hold all of them")

    monkeypatch.setattr(MorphResult, "materialize", refuse)  # folded must come from the streamed frames
    pairs = make_pairs(tmp_path / "in", gen)
    out = tmp_path / "out"
    assert main(["morph", "--pairs", str(pairs), "--out", f"{out}/", *FAST]) == 1  # one row failed
    assert listing(out) == ["failures.csv", "pair0.gif", "pair1.gif", "pair2.gif", "summary.csv"]
    failures = read_csv(out / "failures.csv")
    assert [(f["row"], f["name"]) for f in failures] == [("3", "broken")]
    assert "missing.png" in failures[0]["reason"]
    summary = read_csv(out / "summary.csv")
    assert [s["name"] for s in summary] == ["pair0", "pair1", "pair2"]
    for s in summary:
        assert s["status"] == "morphed" and 0 <= float(s["error_mean_px"]) <= float(s["error_max_px"]) < 5
        assert 0 <= float(s["folded"]) <= 1 and float(s["seconds"]) > 0
    for k in range(3):
        assert iio.imread(out / f"pair{k}.gif", index=None).shape == (4, 32, 36, 3)
    err = capsys.readouterr().err
    assert "row 3 (broken) failed" in err

    # a rerun skips the finished pairs (their files are not touched) and keeps their summary
    stamps = {k: (out / f"pair{k}.gif").stat().st_mtime_ns for k in range(3)}
    (out / "pair1.gif").unlink()  # as if the run had been killed before pair1
    assert main(["morph", "--pairs", str(pairs), "--out", str(out), *FAST]) == 1
    assert (out / "pair0.gif").stat().st_mtime_ns == stamps[0] and (out / "pair2.gif").stat().st_mtime_ns == stamps[2]
    assert (out / "pair1.gif").is_file()
    assert "1 morphed, 2 skipped" in capsys.readouterr().err
    assert [s["status"] for s in read_csv(out / "summary.csv")] == ["morphed"] * 3
    assert listing(out) == ["failures.csv", "pair0.gif", "pair1.gif", "pair2.gif", "summary.csv"]  # no temporaries


def test_all_good_exits_0(tmp_path, gen):
    pairs = make_pairs(tmp_path, gen, n=1, bad=False)
    out = tmp_path / "out"
    assert main(["morph", "--pairs", str(pairs), "--out", str(out), "--format", "png", *FAST]) == 0
    assert listing(out / "pair0") == [f"frame_{k:04d}.png" for k in range(4)]
    assert read_csv(out / "failures.csv") == []


def test_batch_output_matches_a_single_morph(tmp_path, gen):
    pairs = make_pairs(tmp_path, gen, n=1, bad=False)
    morph_pairs(pairs, tmp_path / "out", progress=False, **OPTIONS)
    data = tmp_path / "data"
    single = tmp_path / "single.gif"
    argv = ["morph", str(data / "a0.png"), str(data / "b0.png"), "--points-a", str(data / "a0.pts")]
    assert main([*argv, "--points-b", str(data / "b0.json"), "-o", str(single), *FAST]) == 0
    np.testing.assert_array_equal(iio.imread(single, index=None), iio.imread(tmp_path / "out/pair0.gif", index=None))


def test_max_size_shrinks_each_pairs_animation_as_a_single_morph_is_shrunk(tmp_path, gen):
    # 36 x 32 pictures, --max-size 18: each GIF at 18 x 16, the frames the single morph writes with the same
    # option; PNG frames keep A's size; the batch's projection counts the shrunk frames
    pairs = make_pairs(tmp_path, gen, n=1, bad=False)
    morph_pairs(pairs, tmp_path / "out", progress=False, max_size=18, **OPTIONS)
    assert planned_work(pairs, tmp_path / "new", max_size=18)[0][1:] == ((3, 16, 18), True)
    assert planned_work(pairs, tmp_path / "new", fmt="png", max_size=18)[0][1:] == ((3, 32, 36), False)
    # blending.size (--size) sets every pair's frames, whatever max_size says
    assert planned_work(pairs, tmp_path / "new", max_size=18, size=(20, 24))[0][1:] == ((3, 20, 24), False)
    assert planned_work(pairs, tmp_path / "new", size=40)[0].shape == (3, 40, 40)
    data = tmp_path / "data"
    single = tmp_path / "single.gif"
    argv = ["morph", str(data / "a0.png"), str(data / "b0.png"), "--points-a", str(data / "a0.pts")]
    assert main([*argv, "--points-b", str(data / "b0.json"), "-o", str(single), "--max-size", "18", *FAST]) == 0
    batched = iio.imread(tmp_path / "out/pair0.gif", index=None)
    assert batched.shape[:3] == (4, 16, 18)
    np.testing.assert_array_equal(iio.imread(single, index=None), batched)
    assert (
        main(
            [
                "morph",
                "--pairs",
                str(pairs),
                "--out",
                str(tmp_path / "png"),
                "--format",
                "png",
                "--max-size",
                "18",
                *FAST,
            ]
        )
        == 0
    )
    assert iio.imread(tmp_path / "png/pair0/frame_0000.png").shape[:2] == (32, 36)
    with pytest.raises(ValueError, match="max_size"):
        morph_pairs(pairs, tmp_path / "out", progress=False, max_size=-1, **OPTIONS)
    with pytest.raises(ValueError, match="max_size"):
        planned_work(pairs, tmp_path / "out", max_size=-1)
    with pytest.raises(ValueError, match="size"):
        planned_work(pairs, tmp_path / "out", size=(0, 4))


def test_the_command_line_says_how_many_pairs_max_size_shrinks(tmp_path, gen, capsys):
    pairs = make_pairs(tmp_path, gen, n=2, bad=False)  # 36 x 32 pictures
    argv = ["morph", "--pairs", str(pairs), *FAST[:-1]]  # not --quiet
    assert main([*argv, "--out", str(tmp_path / "small"), "--max-size", "18"]) == 0
    err = capsys.readouterr().err
    assert "2 of the 2 pairs' animations are written with their longer side at --max-size 18" in err
    assert main([*argv, "--out", str(tmp_path / "whole"), "--max-size", "36"]) == 0  # within it: nothing said
    assert "--max-size" not in capsys.readouterr().err


def test_a_batch_projected_past_max_minutes_is_refused_before_any_pair_and_a_rerun_counts_what_is_left(
    tmp_path, gen, capsys
):
    pairs = make_pairs(tmp_path / "in", gen, n=2, bad=False)  # two pairs of 32 x 36 pictures
    out = tmp_path / "out"
    one = work_seconds(f"{out}/pair0.gif", 4, (3, 32, 36))  # a pair's projection: 4 GIF frames of 36 x 32
    limit = ["--max-minutes", repr(1.5 * one / 60)]  # room for one pair, not for both
    argv = ["morph", "--pairs", str(pairs), "--out", f"{out}/", *FAST]
    # the batch's projection is the sum of its pairs': refused before any pair, with it and the flags that allow it
    assert main([*argv, *limit]) == EXIT_BAD_INPUT
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    for words in ("2 pairs of 4 frames each would take at least", "--max-minutes 1", "--no-limit"):
        assert words in err, err
    assert not out.exists()  # nothing written, not even the folder
    # --no-limit starts it
    assert main([*argv, *limit, "--no-limit"]) == EXIT_OK
    assert listing(out) == ["failures.csv", "pair0.gif", "pair1.gif", "summary.csv"]
    capsys.readouterr()
    # a rerun counts only the pairs it will morph: one left is within the limit, both again (--overwrite) are not
    (out / "pair1.gif").unlink()
    assert planned_work(pairs, out) == [(f"{out / 'pair1'}.gif", (3, 32, 36), False)]  # A's (C, H, W), its header
    assert main([*argv, *limit]) == EXIT_OK
    assert "1 morphed, 1 skipped" in capsys.readouterr().err
    assert main([*argv, *limit, "--overwrite"]) == EXIT_BAD_INPUT
    assert "2 pairs of 4 frames each" in capsys.readouterr().err


def test_read_pairs_reports_bad_rows(tmp_path):
    (tmp_path / "p.csv").write_text(
        "# a comment\n\na.png,b.png,a.pts,b.pts\na.png,b.png,a.pts\nc.png,d.png,c.pts,d.pts,a-b\nx,y,z,w,sub/dir\n"
    )
    rows, bad = read_pairs(tmp_path / "p.csv")
    assert [(r.row, r.name) for r in rows] == [(3, "a-b")]
    assert rows[0].image_a == tmp_path / "a.png"  # relative to the CSV's folder
    assert [b[0] for b in bad] == [4, 5, 6]
    assert "got 3 fields" in bad[0][2] and "already used by row 3" in bad[1][2] and "plain file name" in bad[2][2]


def test_ranks_without_a_process_group_write_their_own_summaries(tmp_path, gen, monkeypatch):
    monkeypatch.delenv("MASTER_ADDR", raising=False)
    pairs = make_pairs(tmp_path, gen, n=3, bad=False)
    one = morph_pairs(pairs, tmp_path / "rank1", rank=1, world_size=2, progress=False, **OPTIONS)
    assert one.morphed == ["pair1"]
    assert listing(tmp_path / "rank1") == ["failures.rank1.csv", "pair1.gif", "summary.rank1.csv"]
    assert [s["name"] for s in read_csv(tmp_path / "rank1/summary.rank1.csv")] == ["pair1"]
    zero = morph_pairs(pairs, tmp_path / "rank0", rank=0, world_size=1, progress=False, **OPTIONS)
    assert zero.morphed == ["pair0", "pair1", "pair2"]
    np.testing.assert_array_equal(
        iio.imread(tmp_path / "rank1/pair1.gif", index=None), iio.imread(tmp_path / "rank0/pair1.gif", index=None)
    )
    with pytest.raises(ValueError, match="rank must be in"):
        morph_pairs(pairs, tmp_path / "x", rank=2, world_size=2)


def test_two_processes_under_torch_distributed_give_the_outputs_of_one(tmp_path, gen):
    """Two ranks (gloo on CPU, started as torchrun would: RANK, WORLD_SIZE, MASTER_ADDR, MASTER_PORT)."""
    pairs = make_pairs(tmp_path, gen, n=3)
    code = (
        "import sys; from torchfluidwarp.apps.batch import morph_pairs; "
        "from torchfluidwarp.morph import NaturalSettings; from torchfluidwarp.core.grid import SquareCells; "
        f"r = morph_pairs(sys.argv[1], sys.argv[2], progress=False, settings=NaturalSettings(**{SETTINGS!r}), "
        "frames=4); "
        "print(sorted(r.morphed), len(r.failed))"
    )
    env = {**os.environ, "WORLD_SIZE": "2", "MASTER_ADDR": "127.0.0.1", "MASTER_PORT": str(29500 + os.getpid() % 1000)}
    env.pop("CUDA_VISIBLE_DEVICES", None)
    procs = [
        subprocess.Popen(
            [sys.executable, "-c", code, str(pairs), str(tmp_path / "two")],
            env={**env, "RANK": str(r), "LOCAL_RANK": str(r), "CUDA_VISIBLE_DEVICES": ""},
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        for r in range(2)
    ]
    outs = [p.communicate(timeout=300) for p in procs]
    assert [p.returncode for p in procs] == [0, 0], outs
    # rows pair0, broken, pair1, pair2: rank 0 takes pair0 and pair1, rank 1 broken and pair2; both get the failure
    assert outs[0][0].startswith("['pair0', 'pair1'] 1") and outs[1][0].startswith("['pair2'] 1")
    morph_pairs(pairs, tmp_path / "one", progress=False, rank=0, world_size=1, **OPTIONS)
    assert listing(tmp_path / "two") == listing(tmp_path / "one")
    for k in range(3):
        np.testing.assert_array_equal(
            iio.imread(tmp_path / f"two/pair{k}.gif", index=None), iio.imread(tmp_path / f"one/pair{k}.gif", index=None)
        )
    drop = ("seconds",)
    two = [{k: v for k, v in s.items() if k not in drop} for s in read_csv(tmp_path / "two/summary.csv")]
    one = [{k: v for k, v in s.items() if k not in drop} for s in read_csv(tmp_path / "one/summary.csv")]
    assert [Path(s.pop("output")).name for s in two] == [Path(s.pop("output")).name for s in one]
    assert two == one
    assert read_csv(tmp_path / "two/failures.csv") == read_csv(tmp_path / "one/failures.csv")


def test_stream_frames_renders_large_frames_one_at_a_time(monkeypatch):
    class Fake:
        def __init__(self, nbytes):
            self.nbytes = nbytes

        def bytes_per_frame(self):
            return self.nbytes

        def iter_frames(self, chunk):
            return chunk

    assert batch.stream_frames(Fake(1000)) == 8
    assert batch.stream_frames(Fake(batch.STREAM_BYTES // 3)) == 3
    assert batch.stream_frames(Fake(4 * batch.STREAM_BYTES)) == 1


def test_a_killed_run_resumes_with_each_output_once_and_no_temporaries(tmp_path, gen):
    pairs = make_pairs(tmp_path, gen, n=3, bad=False)
    out = tmp_path / "out"
    argv = [sys.executable, "-m", "torchfluidwarp.apps.cli", "morph", "--pairs", str(pairs), "--out", str(out)]
    argv += ["--grid", "12", "--steps", "2", "--max-iter", "5", "--frames", "150", "--quiet"]
    proc = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        while not (out / "pair0.gif").exists() and proc.poll() is None:
            time.sleep(0.02)
    finally:
        proc.kill()  # SIGKILL: no clean-up runs, a temporary output may be left behind
        proc.wait()
    (out / ".pair2.gif.0123abcd.tmp.gif").write_bytes(b"GIF89a half")  # as a kill in pair2's write leaves it
    before = (out / "pair0.gif").stat().st_mtime_ns
    assert main(argv[3:]) == 0
    assert listing(out) == ["failures.csv", "pair0.gif", "pair1.gif", "pair2.gif", "summary.csv"]
    assert (out / "pair0.gif").stat().st_mtime_ns == before  # finished before the kill: not redone
    assert [s["name"] for s in read_csv(out / "summary.csv")] == ["pair0", "pair1", "pair2"]
    for k in range(3):
        assert len(iio.imread(out / f"pair{k}.gif", index=None)) == 150


def test_streamed_frames_hand_the_heaps_free_memory_back_after_each(monkeypatch):
    # the frames pass unchanged, one at a time (nothing read ahead), and the C heap is trimmed once before the
    # first (what the fit freed) and after each; where the C library has no malloc_trim, they pass all the same
    calls = []
    monkeypatch.setattr(batch, "_malloc_trim", lambda: lambda pad: calls.append(("trim", pad)))
    frames = [torch.full((1, 2, 2), float(k)) for k in range(3)]

    def produced():
        for k, frame in enumerate(frames):
            calls.append(("frame", k))
            yield frame

    stream = batch.returning_memory(produced())
    first = next(stream)
    assert first is frames[0] and calls == [("trim", 0), ("frame", 0)]
    rest = list(stream)
    assert rest == frames[1:]
    assert calls == [("trim", 0), ("frame", 0), ("trim", 0), ("frame", 1), ("trim", 0), ("frame", 2), ("trim", 0)]
    monkeypatch.setattr(batch, "_malloc_trim", lambda: None)
    assert list(batch.returning_memory(iter(frames))) == frames


def test_malloc_trim_is_glibcs_on_linux_and_none_elsewhere():
    trim = batch._malloc_trim()
    if not sys.platform.startswith("linux"):
        assert trim is None
        return
    assert trim is not None
    assert trim(0) in (0, 1)  # 1 if memory went back to the system


def test_the_summarys_warnings_name_the_command_lines_flags(tmp_path, gen):
    # a pair whose marks cross warns with advice; the command line's summary words it as its flags, Python's
    # as Python's names
    pairs = make_pairs(tmp_path, gen, n=1, bad=False)
    crossing = torch.tensor([[8.0, 8.0], [24.0, 9.0], [15.0, 22.0], [10.0, 26.0]])
    write_points(tmp_path / "data/a0.pts", crossing)
    write_points(tmp_path / "data/b0.json", crossing[[1, 0, 2, 3]])  # the first two swap sides
    assert main(["morph", "--pairs", str(pairs), "--out", str(tmp_path / "cli"), *FAST]) == 0
    (row,) = read_csv(tmp_path / "cli/summary.csv")
    assert "the marks cross: points 0 and 1" in row["warnings"]
    assert "--report JSON names the points let go" in row["warnings"] and "result." not in row["warnings"]
    morph_pairs(pairs, tmp_path / "py", progress=False, **OPTIONS)
    (row,) = read_csv(tmp_path / "py/summary.csv")
    assert "result.let_go (and result.error) names the points let go" in row["warnings"]


def test_a_rows_point_files_are_named_in_its_failure(tmp_path, gen):
    pairs = make_pairs(tmp_path, gen, n=1, bad=False)
    write_points(tmp_path / "data" / "normalised.pts", POINTS_A / 36)  # fractions of the picture
    write_points(tmp_path / "data" / "swapped.pts", POINTS_A.flip(-1) + torch.tensor([0.0, 20.0]))  # (y, x), off
    with open(pairs, "a") as fp:
        fp.write("data/a0.png,data/b0.png,data/a0.pts,data/normalised.pts,normalised\n")
        fp.write("data/a0.png,data/b0.png,data/swapped.pts,data/b0.json,swapped\n")
    out = tmp_path / "out"
    assert main(["morph", "--pairs", str(pairs), "--out", str(out), *FAST]) == 1
    reasons = {f["name"]: f["reason"] for f in read_csv(out / "failures.csv")}
    assert (
        "points file '" in reasons["normalised"]
        and "normalised.pts': all 3 points lie within [0, 1]" in reasons["normalised"]
    )
    assert "swapped.pts' has a point outside the 36 x 32 image" in reasons["swapped"], reasons
