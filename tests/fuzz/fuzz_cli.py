"""Worker side: the CLI cases, run in-process through ``torchfluidwarp.apps.cli.main`` (see ``fuzz_cases.py``).

The outcome must be exit 0 with the output written, or exit 2 (bad input) or 3 (the flow blew up) with one line on
stderr that names the bad option or file, no traceback, and nothing left behind.
"""

from __future__ import annotations

import contextlib
import io
import json
import traceback
from pathlib import Path
from typing import Any

import fuzz_build as fb
import torch
from fuzz_entries import inside, spread_points

FILE_VARIANTS = {"nested_json", "huge_numbers", "nan_json", "garbage", "empty_file", "truncated", "bomb"}


def cli_file(variant: str, name: str, folder: Path, good: Path, points: torch.Tensor) -> Path:
    if variant == "missing":
        return folder / f"missing_{name}"
    if variant == "folder":
        (folder / "a_folder").mkdir(exist_ok=True)
        return folder / "a_folder"
    if variant == "identical":
        path = folder / f"identical_{name}.json"
        path.write_text(fb.points_json(points[:1].expand_as(points)))
        return path
    if variant == "fewer":
        path = folder / f"fewer_{name}.json"
        path.write_text(fb.points_json(points[:-1]))
        return path
    suffix = ".json" if variant in ("nested_json", "huge_numbers", "nan_json") else good.suffix
    path = folder / f"{variant}_{name}{suffix}"
    path.write_bytes(fb.FILE_CONTENT[variant]())
    return path


def base_argv(command: str, d: dict[str, Any], folder: Path, gen: torch.Generator) -> list[str]:
    H, W, g, T, M = (d[k] for k in "HWgTM")
    (folder / "a.png").write_bytes(fb.png_bytes(H, W, 1))
    (folder / "b.png").write_bytes(fb.png_bytes(H, W, 2))
    pa = spread_points(M, H, W, gen)
    (folder / "a.json").write_text(fb.points_json(pa))
    pb = inside(pa + torch.randn(M, 2, generator=gen), H, W)
    (folder / "b.json").write_text(fb.points_json(pb))
    (folder / "config.json").write_text(json.dumps({"steps": T}))
    if command == "animate":
        return ["animate", "a.png", "-o", "out.gif", "--grid", str(g), "--steps", str(T), "--max-size", "24",
                "--brush", "4,4,1,0,3,0.1,0.5", "--config", "config.json", "-q"]  # fmt: skip
    if command == "morph":
        return ["morph", "a.png", "b.png", "--points-a", "a.json", "--points-b", "b.json", "-o", "out.gif",
                "--frames", "3", "--steps", str(T), "--grid", str(g), "--max-iter", "1", "-q"]  # fmt: skip
    if command == "demo":
        return ["demo", "-o", "out.gif", "--frames", "2", "--steps", "1", "--grid", "8", "--max-iter", "1", "-q"]
    return ["studio"]


POSITIONAL = {"IMAGE": "a.png", "A": "a.png", "B": "b.png"}


def run_cli(spec: dict[str, Any], case: Path, tmp: Path) -> dict[str, str]:
    from torchfluidwarp.apps.cli import main

    command = spec["entry"]
    gen = torch.Generator().manual_seed(spec["seed"])
    argv = base_argv(command, spec["dims"], case, gen)
    points = torch.tensor(json.loads((case / "a.json").read_text()))
    names, output, helped = [], "out.gif", False
    for opt, value in spec["perturb"]:
        names += [opt.lstrip("-").lower(), opt.lstrip("-").lower().replace("-", "_")]
        if opt in POSITIONAL or opt in ("--points-a", "--points-b", "--config"):
            old = POSITIONAL.get(opt) or argv[argv.index(opt) + 1]
            new = str(cli_file(value, opt.strip("-").lower(), case, case / old, points))
            argv[argv.index(old) if opt in POSITIONAL else argv.index(opt) + 1] = new
            names.append(Path(new).name.lower())
            continue
        if opt == "-o":
            if value == "folder":
                (case / "out_folder").mkdir()
                value = "out_folder"
            if value == "existing.gif":
                (case / value).write_bytes(b"keep me")
            argv[argv.index("-o") + 1] = output = value
            names += ["output", value.lower()] if value else ["output"]
            continue
        if opt == "--help":
            helped = True
            continue
        if opt == "--brush":
            value = f"4,4,1,0,3,0.1,{value}"
        elif opt == "--stiff":
            value = f"4,4,3,{value}"
        if opt in argv:
            argv[argv.index(opt) + 1] = value
        else:
            argv += [opt, value]
    if command == "studio":
        argv.append("--help")  # the studio never starts a server here: parsing ends with --help or an error
        helped = True
    files, err = fb_listing(case), io.StringIO()
    try:
        with contextlib.redirect_stderr(err):
            rc = main(argv)
    except SystemExit as exc:
        rc = exc.code if isinstance(exc.code, int) else 1
    except BaseException as exc:  # noqa: BLE001  (an escaped exception is the defect being looked for)
        tb = "".join(traceback.format_exception(exc)[-6:])
        return {"verdict": "fail", "detail": f"argv {argv}: exception escaped main: {exc!r}\n{tb}"}
    lines = [ln for ln in err.getvalue().splitlines() if ln.strip()]
    verdict = {"verdict": "ok" if rc == 0 else "refused", "detail": f"argv {argv}: exit {rc}: {lines[:3]}"}
    if "Traceback" in err.getvalue():
        verdict["verdict"] = "fail"
    elif rc == 0:
        out = case / output
        if not helped and not (out.is_file() or (out.is_dir() and any(out.iterdir()))):
            verdict["verdict"] = "fail"
            verdict["detail"] += "; exit 0 but no output"
    elif rc not in (2, 3) or len(lines) != 1:  # 2: bad input; 3: the flow blew up (torchfluidwarp.errors)
        verdict["verdict"] = "fail"
        verdict["detail"] += "; want exit 2 or 3 with one line on stderr"
    elif fb_listing(case) != files:
        verdict["verdict"] = "fail"
        verdict["detail"] += "; files changed in the case folder"
    elif not any(n in lines[0].lower() for n in names):
        verdict["verdict"] = "fail"
        verdict["detail"] += f"; the message does not name any of {names}"
    return check_tmp(tmp, verdict)


def fb_listing(folder: Path) -> dict[str, str]:
    from fuzz_worker import listing

    return listing(folder)


def check_tmp(tmp: Path, verdict: dict[str, str]) -> dict[str, str]:
    from fuzz_worker import check_tmp

    return check_tmp(tmp, verdict)
