"""The command line's exit codes follow the library's error taxonomy (:mod:`torchfluidwarp.errors`).

2 and one line for the user's errors, 3 and one line for a flow that blew up, 1 and the traceback for anything
else: a library bug (injected here by replacing a function the command line calls) must never look like the
user's mistake.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import pytest
import torch

from torchfluidwarp._checks import check_memory
from torchfluidwarp.apps import animate, cli_morph, cli_sequence
from torchfluidwarp.apps.cli import build_parser, main
from torchfluidwarp.apps.cli_args import EXIT_BAD_INPUT, EXIT_BUG, EXIT_FLOW_BLEW_UP, fail, flags
from torchfluidwarp.errors import FlowBlewUp, Hint, InputError, InputTypeError
from torchfluidwarp.io import write_image, write_points

BRUSH = "12,12,1,0,6,0.1,0.5"
FAST_ANIMATE = ["--grid", "8", "--steps", "2", "--quiet"]
FAST_MORPH = ["--grid", "8", "--steps", "2", "--max-iter", "3", "--frames", "3", "--quiet"]
SUBSTEPS_HINT = Hint(
    "reduce the forces, the initial velocity or dt, or raise the limit with {setting}",
    "max_substeps",
    spelling="max_substeps (MapConfig(max_substeps=...) for FluidWarp and the maps)",
    otherwise="reduce the forces, the initial velocity or dt",
)


@pytest.fixture
def photo(tmp_path: Path, gen: torch.Generator) -> Path:
    return write_image(tmp_path / "photo.png", torch.rand(3, 24, 24, generator=gen))


@pytest.fixture
def pair(tmp_path: Path, gen: torch.Generator) -> list[str]:
    points = torch.tensor([[5.0, 5.0], [18.0, 6.0], [10.0, 18.0]])
    files = [
        write_image(tmp_path / "a.png", torch.rand(3, 24, 24, generator=gen)),
        write_image(tmp_path / "b.png", torch.rand(3, 24, 24, generator=gen)),
        write_points(tmp_path / "a.pts", points),
        write_points(tmp_path / "b.pts", points + 1.0),
    ]
    return [str(files[0]), str(files[1]), "--points-a", str(files[2]), "--points-b", str(files[3])]


def raiser(error: BaseException):
    def raise_it(*args, **kwargs):
        raise error

    return raise_it


def one_line(err: str) -> str:
    assert err.count("\n") == 1 and "Traceback" not in err, err
    return err


def run_animate(photo: Path, tmp_path: Path) -> int:
    return main(["animate", str(photo), "-o", str(tmp_path / "out.gif"), "--brush", BRUSH, *FAST_ANIMATE])


def run_morph(pair: list[str], tmp_path: Path, *extra: str) -> int:
    return main(["morph", *pair, "-o", str(tmp_path / "m.gif"), *FAST_MORPH, *extra])


# --------------------------------------------------------------------------- a library bug: exit 1, traceback

BUGS = [RuntimeError("boom in the solver"), ValueError("plain value error"), IndexError("index 7"), TypeError("None")]


@pytest.mark.parametrize("bug", BUGS, ids=lambda e: type(e).__name__)
def test_a_library_bug_in_animate_exits_1_with_its_traceback(photo, tmp_path, capsys, monkeypatch, bug):
    monkeypatch.setattr(animate, "animate_frames", raiser(bug))
    assert run_animate(photo, tmp_path) == EXIT_BUG
    err = capsys.readouterr().err
    assert "Traceback (most recent call last)" in err and f"{type(bug).__name__}: {bug}" in err
    assert "a bug in torchfluidwarp" in err.splitlines()[-1]
    assert not (tmp_path / "out.gif").exists()


@pytest.mark.parametrize("bug", BUGS, ids=lambda e: type(e).__name__)
def test_a_library_bug_in_morph_exits_1_with_its_traceback(pair, tmp_path, capsys, monkeypatch, bug):
    monkeypatch.setattr(cli_morph, "morph", raiser(bug))  # the morph subcommand's own except block lets it through
    assert run_morph(pair, tmp_path) == EXIT_BUG
    err = capsys.readouterr().err
    assert "Traceback (most recent call last)" in err and f"{type(bug).__name__}: {bug}" in err


def test_a_library_bug_in_average_exits_1_with_its_traceback(pair, tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(cli_sequence, "average", raiser(ValueError("plain value error")))
    rc = main(["average", pair[0], pair[1], "--points", pair[3], pair[5], "-o", str(tmp_path / "m.png"), "-q"])
    assert rc == EXIT_BUG
    assert "Traceback (most recent call last)" in capsys.readouterr().err


# ------------------------------------------------------------------------ the user's errors: exit 2, one line


@pytest.mark.parametrize(
    "error",
    [
        InputError("image must be (C, H, W), got shape (2, 3)", argument="image"),
        InputTypeError("dtype must be a torch.dtype, got str 'float32'", argument="dtype"),
        PermissionError(13, "Permission denied", "out.gif"),
    ],
    ids=lambda e: type(e).__name__,
)
def test_an_input_error_exits_2_with_one_line(photo, tmp_path, capsys, monkeypatch, error):
    monkeypatch.setattr(animate, "animate_frames", raiser(error))
    assert run_animate(photo, tmp_path) == EXIT_BAD_INPUT
    err = one_line(capsys.readouterr().err)
    assert err.startswith("torchfluidwarp animate: error: ")
    assert (error.message if isinstance(error, InputError | InputTypeError) else "Permission denied") in err


def test_an_input_error_in_morph_exits_2_and_names_the_flag_that_set_the_argument(pair, tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(cli_morph, "morph", raiser(InputError("max_iter must be >= 1, got 0", argument="max_iter")))
    assert run_morph(pair, tmp_path) == EXIT_BAD_INPUT
    err = one_line(capsys.readouterr().err)
    assert err == "torchfluidwarp morph: error: argument --max-iter: max_iter must be >= 1, got 0\n"


def test_an_argument_the_command_line_has_no_option_for_is_not_given_one(pair, tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(cli_morph, "morph", raiser(InputError("history_size must be >= 1", argument="history_size")))
    assert run_morph(pair, tmp_path) == EXIT_BAD_INPUT
    assert one_line(capsys.readouterr().err) == "torchfluidwarp morph: error: history_size must be >= 1\n"


def test_missing_files_exit_2(pair, tmp_path, capsys):
    assert run_morph([str(tmp_path / "nope.png"), *pair[1:]], tmp_path) == EXIT_BAD_INPUT
    assert "nope.png" in one_line(capsys.readouterr().err)
    assert run_morph([*pair[:3], str(tmp_path / "nope.pts"), *pair[4:]], tmp_path) == EXIT_BAD_INPUT
    assert "nope.pts" in one_line(capsys.readouterr().err)


def test_the_command_lines_own_errors_exit_2(photo, tmp_path, capsys):
    assert main(["animate", str(photo), "-o", str(tmp_path / "a.gif"), *FAST_ANIMATE]) == EXIT_BAD_INPUT
    assert "--brush" in one_line(capsys.readouterr().err)
    assert main(["animate", str(photo), "-o", str(tmp_path / "a.gif"), "--brush", BRUSH, "--grid", "8", "8", "8"]) == 2
    assert "--grid takes 1 or 2 integers" in one_line(capsys.readouterr().err)
    assert main(["morph", "--frames", "1"]) == EXIT_BAD_INPUT  # argparse's own usage error
    assert "--frames" in one_line(capsys.readouterr().err)


# ------------------------------------------------------------------------- a flow that blew up: exit 3, one line


def test_a_flow_that_blew_up_exits_3_with_its_message(photo, tmp_path, capsys, monkeypatch):
    error = FlowBlewUp("the flow needs 9000 sub-steps in one step, above the limit of 4096", hint=SUBSTEPS_HINT)
    monkeypatch.setattr(animate, "animate_frames", raiser(error))
    assert run_animate(photo, tmp_path) == EXIT_FLOW_BLEW_UP
    err = one_line(capsys.readouterr().err)
    assert "9000 sub-steps" in err and "reduce the forces, the initial velocity or dt" in err
    # the command line has no option for max_substeps: the hint says what it can change instead
    assert "max_substeps" not in err and "MapConfig" not in err


def test_a_real_flow_too_strong_exits_3(photo, tmp_path, capsys):
    argv = ["animate", str(photo), "-o", str(tmp_path / "o.gif"), "--brush", "12,12,1,0,5,0,100000", "--steps", "3"]
    assert main([*argv, "--grid", "8", "--quiet"]) == EXIT_FLOW_BLEW_UP
    assert "sub-steps" in one_line(capsys.readouterr().err)
    assert not (tmp_path / "o.gif").exists()


# -------------------------------------------------------------- the hints the command line had, from the parser


def test_the_memory_hint_names_the_max_memory_flag(pair, tmp_path, capsys):
    assert run_morph(pair, tmp_path, "--max-memory", "0.00001") == EXIT_BAD_INPUT
    err = one_line(capsys.readouterr().err)
    assert "above the limit of" in err and err.rstrip().endswith(
        "ask for less, or raise the limit with --max-memory GIB"
    )
    assert "max_memory" not in err


def test_the_memory_hint_without_a_max_memory_flag_says_what_the_user_can_do(capsys):
    with pytest.raises(InputError) as info:
        check_memory("FluidWarp(frames=9)", 2.0**40, None, "MapConfig(max_memory=...)")
    assert "raise the limit with MapConfig(max_memory=...)" in str(info.value)  # Python's terms
    animate = _subparser("animate")
    assert "max_memory" not in flags(animate)
    assert fail("animate", info.value, flags(animate)) == EXIT_BAD_INPUT
    err = one_line(capsys.readouterr().err)
    assert err.rstrip().endswith("above the limit of 8.0 GiB; ask for less") and "max_memory" not in err


def _subparser(command: str) -> argparse.ArgumentParser:
    for action in build_parser()._actions:
        if isinstance(action, argparse._SubParsersAction):
            return action.choices[command]
    raise AssertionError("no subcommands")


@pytest.mark.parametrize("command", ["animate", "morph", "demo", "average"])
def test_every_option_is_found_by_the_argument_it_sets(command):
    parser = _subparser(command)
    options = flags(parser)
    for action in parser._actions:
        if action.option_strings:
            assert options[action.dest] is action
        else:  # a positional IMAGE is not the library's argument called image
            assert action.dest not in options or options[action.dest] is not action
    if command != "animate":
        assert options["max_memory"].option_strings == ["--max-memory"] and options["max_memory"].metavar == "GIB"
