"""An honest command line (#31): arguments and files checked before torch is imported, work projected past a limit
refused with its estimate, SIGTERM cleaning up as Ctrl-C does, warnings on one line pointing at the caller. (The
printed time and its parts: ``test_cli_morph.py``; the face model's log lines: ``tests/correspond``.)"""

from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
import time
import warnings
from pathlib import Path

import pytest
import torch

from torchfluidwarp.apps import cli_args
from torchfluidwarp.apps.cli import _check_early, main
from torchfluidwarp.apps.cli_args import EXIT_BAD_INPUT, EXIT_TERMINATED, check_work, command_run
from torchfluidwarp.errors import AdvisedWarning, Hint, InputError
from torchfluidwarp.io import write_image, write_points

# run main() in a fresh interpreter and say whether torch was imported by the time it returned
PROBE = (
    "import sys; from torchfluidwarp.apps.cli import main; rc = main(sys.argv[1:]); "
    "print('torch' in sys.modules); sys.exit(rc)"
)
BRUSH = "12,12,1,0,6,0.1,0.5"


def run_cli(*argv: str, cwd: Path, timeout: float = 120) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-c", PROBE, *argv], capture_output=True, text=True, timeout=timeout, cwd=cwd, check=False
    )


@pytest.fixture
def files(tmp_path: Path, gen: torch.Generator) -> Path:
    write_image(tmp_path / "a.png", torch.rand(3, 24, 24, generator=gen))
    write_points(tmp_path / "a.pts", torch.tensor([[5.0, 5.0], [15.0, 8.0], [10.0, 18.0]]))
    (tmp_path / "taken.gif").write_bytes(b"keep me")
    return tmp_path


@pytest.mark.parametrize(
    ("argv", "words"),
    [
        (["morph", "missing.png", "a.png", "-o", "o.gif"], "cannot read image 'missing.png': no such file"),
        (["morph", "a.png", "a.png", "--frames", "30", "--points-a", "a.pts", "--points-b", "no.pts"], "'no.pts'"),
        (
            ["morph", "a.png", "a.png", "-o", "o.txt"],
            "unknown suffix '.txt'; use .gif, .mp4, .webp or a folder ending in '/'",
        ),
        (["morph", "a.png", "a.png", "-o", "mid.png"], "or add --frame T (--frame 0.5: the middle image) to write the"),
        (["morph", "a.png", "a.png", "--output=taken.gif"], "already exists"),
        (["morph", "a.png", "a.png", "--frame", "0.5", "-o", "mid.xyz"], "an image needs a suffix"),
        (["animate", "missing.png", "-o", "o.gif", "--brush", BRUSH], "cannot read image 'missing.png'"),
        (["animate", "a.png", "-o", "o.gif", "--brush", "1,2,x"], "argument --brush: expected comma-separated"),
        (["animate", "a.png", "-o", "o.gif", "--brush", "1,2,3"], "brush needs 7 or 8 values, got 3"),
        (["animate", "a.png", "--config", "none.json", "-o", "o.gif"], "cannot read config 'none.json'"),
        (["average", "a.png", "gone.png", "--points", "a.pts", "a.pts"], "cannot read image 'gone.png'"),
        (["demo", "-o", "taken.gif"], "already exists"),
    ],
)
def test_a_bad_file_or_argument_is_refused_before_torch_is_imported(files, argv, words):
    done = run_cli(*argv, cwd=files)
    assert done.returncode == EXIT_BAD_INPUT, done.stderr
    assert done.stdout.strip() == "False", "torch was imported before the refusal"
    assert words in done.stderr and len(done.stderr.strip().splitlines()) == 1, done.stderr
    assert (files / "taken.gif").read_bytes() == b"keep me"


def test_a_missing_file_is_reported_in_well_under_the_time_torch_takes_to_import(files):
    begin = time.perf_counter()
    subprocess.run([sys.executable, "-c", "import torch"], check=True, timeout=120)
    torch_import = time.perf_counter() - begin
    begin = time.perf_counter()
    done = run_cli("morph", "missing.png", "a.png", "-o", "o.gif", cwd=files)
    refusal = time.perf_counter() - begin
    assert done.returncode == EXIT_BAD_INPUT, done.stderr
    # the same interpreter start on the same machine, at the same moment: generous on a loaded machine
    assert refusal < max(1.0, 0.75 * torch_import), (refusal, torch_import)


@pytest.mark.parametrize(
    "argv",
    [
        ["morph", "a.png", "a.png", "--frames", "30", "-o", "o.gif"],  # "30" is no image
        ["morph", "--grid", "16", "a.png", "a.png"],  # nor is "16" or what follows an unknown option
        ["morph", "--points", "a.pts", "a.pts", "-o", "o.gif"],
        ["morph", "a.png", "a.png", "-o", "o.gif", "--over"],  # an abbreviation of --overwrite: the parser's
        ["morph", "a.png", "a.png", "-o", "taken.gif", "--overwrite"],
        ["morph", "--pairs", "a.pts", "--out", "folder/"],
        ["morph", "missing.png", "--help"],
        ["animate", "a.png", "-o", "o.gif", "--brush", BRUSH, "--stiff", "1,2,3,4", "--steps", "-1"],
        ["morph", "--", "-x.png", "a.png"],
        ["studio", "missing.png"],
    ],
)
def test_the_early_checks_refuse_only_what_is_certain(files, monkeypatch, argv):
    monkeypatch.chdir(files)
    assert _check_early(argv) is None


def test_an_output_folder_and_a_folder_given_as_image(files, monkeypatch, capsys):
    monkeypatch.chdir(files)
    (files / "pics").mkdir()
    assert _check_early(["morph", "pics", "a.png", "-o", "frames/"]) == EXIT_BAD_INPUT
    assert "cannot read image 'pics': it is a folder, not a file" in capsys.readouterr().err


# ------------------------------------------------------------------------------------------- limits


def limits(**given: object) -> argparse.Namespace:
    return argparse.Namespace(**{"max_minutes": cli_args.MAX_MINUTES, "no_limit": False, **given})


def test_work_past_the_limit_is_refused_with_its_estimate_and_the_flags_that_allow_it():
    with pytest.raises(InputError) as caught:
        check_work(limits(), "out.gif", 100_000, (3, 512, 512))
    message = str(caught.value)
    for words in ("100000 frames of 512x512", "at least 87 min", "24.5 GiB", "--max-minutes 88", "--no-limit"):
        assert words in message, message
    check_work(limits(max_minutes=88.0), "out.gif", 100_000, (3, 512, 512))
    check_work(limits(no_limit=True), "out.gif", 10**9, (3, 512, 512))
    check_work(limits(), "out.gif", 30, (3, 6000, 6000))  # a default morph of two big photographs starts


def test_mp4_is_projected_faster_than_gif():
    check_work(limits(), "out.mp4", 20_000, (3, 512, 512))  # 4.4 min at least as MP4
    with pytest.raises(InputError, match="at least 17 min"):
        check_work(limits(), "out.gif", 20_000, (3, 512, 512))


def test_the_demo_refuses_a_hundred_thousand_frames_and_writes_nothing(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    assert main(["demo", "--frames", "100000"]) == EXIT_BAD_INPUT
    err = capsys.readouterr().err
    assert "would take at least" in err and "--no-limit" in err and len(err.strip().splitlines()) == 1, err
    assert list(tmp_path.iterdir()) == []


# -------------------------------------------------------------------------------------------- SIGTERM


def test_sigterm_mid_write_leaves_no_temporary_file(tmp_path):
    # a demo long enough to be stopped while it writes: the frames stream into a hidden temporary GIF
    argv = ["demo", "--frames", "400", "--grid", "16", "--steps", "3", "--max-iter", "5", "--no-limit", "-q"]
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    proc = subprocess.Popen(
        [sys.executable, "-m", "torchfluidwarp.apps.cli", *argv, "-o", "out.gif"],
        cwd=tmp_path,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        deadline = time.monotonic() + 240
        while not list(tmp_path.glob(".out.gif.*")) and proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.1)
        assert list(tmp_path.glob(".out.gif.*")), "the run never started writing"
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert proc.returncode == EXIT_TERMINATED, err
    assert "terminated" in err and "Traceback" not in err, err
    assert list(tmp_path.iterdir()) == []  # neither the output nor its temporary file


def test_the_sigterm_handler_is_the_runs_only():
    before = signal.getsignal(signal.SIGTERM)
    with command_run("morph"):
        assert signal.getsignal(signal.SIGTERM) is not before
        with pytest.raises(cli_args.Terminated):
            os.kill(os.getpid(), signal.SIGTERM)
            time.sleep(1)  # the handler raises in the main thread at the next bytecode
    assert signal.getsignal(signal.SIGTERM) is before
    assert issubclass(cli_args.Terminated, KeyboardInterrupt)  # what cleans up after Ctrl-C cleans up after it


# --------------------------------------------------------------------------------- log lines and warnings


def test_warnings_during_a_run_are_one_line_without_a_source_line(capsys):
    with command_run("morph"):
        warnings.warn("the marks cross at 3 points\nsecond line", UserWarning, stacklevel=1)
    err = capsys.readouterr().err
    assert err == "torchfluidwarp morph: warning: the marks cross at 3 points\n", err
    assert warnings.showwarning.__module__ == "warnings"  # restored


def test_a_warnings_advice_names_the_commands_flags(tmp_path, capsys):
    # the library's advice names Python settings (result.let_go, NaturalSettings.straightness); the command line
    # names its own flags instead
    with command_run("morph", {"straightness": argparse.Action(["--straightness"], "straightness", metavar="S")}):
        warnings.warn(
            AdvisedWarning("the maps fold", hint=Hint("raise {setting}", "straightness", spelling="NaturalSettings")),
            stacklevel=1,
        )
    assert capsys.readouterr().err == "torchfluidwarp morph: warning: the maps fold; raise --straightness S\n"
    # a real morph whose marks cross: the warnings name --report and --straightness, no Python name
    picture = torch.rand(3, 40, 40, generator=torch.Generator().manual_seed(0))
    write_image(tmp_path / "a.png", picture)
    pa = torch.tensor([[8.0, 8.0], [30.0, 8.0], [20.0, 30.0], [10.0, 25.0]])
    write_points(tmp_path / "a.pts", pa)
    write_points(tmp_path / "b.pts", pa[[1, 0, 2, 3]])  # the first two swap sides
    argv = ["morph", str(tmp_path / "a.png"), str(tmp_path / "a.png"), "--points-a", str(tmp_path / "a.pts")]
    argv += ["--points-b", str(tmp_path / "b.pts"), "-o", str(tmp_path / "m.gif"), "--frames", "3", "--grid", "12"]
    assert main([*argv, "--steps", "3", "--max-iter", "5"]) == 0
    err = capsys.readouterr().err
    assert "warning: the marks cross: points 0 and 1" in err and "--report JSON names the points let go" in err
    assert "result." not in err and "Settings" not in err


def test_library_warnings_point_at_the_callers_line():
    # warn called from inside the package (cli_args' lazy wrapper around _checks.warn) names this line
    warn_from_the_package = cli_args._library("torchfluidwarp._checks", "warn")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        line = sys._getframe().f_lineno + 1
        warn_from_the_package("about your call")
    assert (caught[0].filename, caught[0].lineno) == (__file__, line)
