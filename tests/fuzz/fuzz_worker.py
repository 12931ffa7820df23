"""The fuzz worker: a long-lived process that runs fuzz cases and judges each outcome (see ``fuzz_cases.py``).

Protocol: one JSON spec per line on stdin, one JSON verdict per line on the original stdout,
``{"verdict": "ok" | "refused" | "fail", "detail": str}``. Everything the cases print goes to ``/dev/null``
(stderr of the CLI cases is captured and judged). The parent kills and restarts the worker when a case
runs past its timeout.

Reproduce one case: ``python tests/fuzz/fuzz_worker.py '<spec as printed by the failing test>'`` prints its
verdict and, for a failure, the traceback.
"""

from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import json
import math
import os
import shutil
import sys
import tempfile
import traceback
import warnings
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).parent))

ALLOWED = (ValueError, TypeError, FileNotFoundError, IsADirectoryError, NotADirectoryError, FileExistsError)


def listing(folder: Path) -> dict[str, str]:
    out = {}
    for p in sorted(folder.rglob("*")):
        out[str(p.relative_to(folder))] = hashlib.sha1(p.read_bytes()).hexdigest() if p.is_file() else "dir"
    return out


def snapshot(args: dict[str, Any]) -> dict[str, Any]:
    from torch import Tensor

    return {k: v.detach().clone() for k, v in args.items() if isinstance(v, Tensor)}


def changed_inputs(args: dict[str, Any], before: dict[str, Any]) -> list[str]:
    out = []
    for k, old in before.items():
        new = args[k].detach()
        same = new.shape == old.shape and new.dtype == old.dtype
        if same and new.numel():
            eq = (
                (new == old) | ((new != new) & (old != old))
                if new.is_floating_point() or new.is_complex()
                else new == old
            )
            same = bool(eq.all())
        if not same:
            out.append(k)
    return out


def non_finite(value: Any, where: str = "result", depth: int = 0) -> str | None:
    """Where ``value`` holds a non-finite float (or ``None``)."""
    import torch

    if depth > 4:
        return None
    if isinstance(value, torch.Tensor):
        v = value.detach()
        if (v.is_floating_point() or v.is_complex()) and v.numel() and not bool(torch.isfinite(v).all()):
            return f"{where}: {tuple(v.shape)} {v.dtype} holds non-finite values"
        return None
    if isinstance(value, float):
        return None if math.isfinite(value) else f"{where} = {value!r}"
    if isinstance(value, dict):
        items = list(value.items())
    elif isinstance(value, (list, tuple)):
        items = list(enumerate(value))
    elif dataclasses.is_dataclass(value) and not isinstance(value, type):
        items = [(f.name, getattr(value, f.name)) for f in dataclasses.fields(value)]
    elif isinstance(value, torch.nn.Module):
        items = list(value.named_parameters()) + list(value.named_buffers())
    elif type(value).__module__.startswith("torchfluidwarp"):
        items = [(k, v) for k, v in vars(value).items() if not k.startswith("__")]
    else:
        return None
    for k, v in items:
        found = non_finite(v, f"{where}.{k}", depth + 1)
        if found:
            return found
    return None


def names_for(entry: str, kind: str, arg: str, value: Any) -> list[str]:
    names = [arg, arg.replace("_", " "), arg.replace("_", "-")]
    if kind.startswith("path") and isinstance(value, (str, Path)) and str(value):
        names += [Path(value).name, "path"]
    if kind == "bytes":
        names += ["data", "image"]
    if entry == "RandomFluidWarp":
        names.append("sample")  # the transform's one argument: the sample holding the image, mask and boxes
    return [n.lower() for n in names if n]


def judge_error(exc: BaseException, names: list[str], valid: bool) -> dict[str, str]:
    text = f"{type(exc).__name__}: {exc}"
    tb = "".join(traceback.format_exception(exc)[-6:])
    if valid:
        return {"verdict": "fail", "detail": f"valid input refused: {text}\n{tb}"}
    from torchfluidwarp.errors import FlowBlewUp  # imported by now: the worker imports the package first

    if not isinstance(exc, (*ALLOWED, FlowBlewUp)):  # a blown-up flow is the caller's forces, not a bug
        return {"verdict": "fail", "detail": f"unexpected {text}\n{tb}"}
    if names and not any(n in str(exc).lower() for n in names):
        return {"verdict": "fail", "detail": f"message does not name {names[0]!r}: {text}\n{tb}"}
    return {"verdict": "refused", "detail": text}


def run_api(spec: dict[str, Any], case: Path, tmp: Path) -> dict[str, str]:
    import fuzz_build as fb
    import torch
    from fuzz_cases import ENTRIES, VALID
    from fuzz_entries import BASE, PATHS, call

    entry = spec["entry"]
    args = BASE[entry](spec["dims"], torch.Generator().manual_seed(spec["seed"]), case)
    if entry in PATHS:
        args["path"] = case / PATHS[entry]
    names, valid = [], True
    for arg, variant in spec["perturb"]:
        kind = ENTRIES[entry][arg]
        base = args.get(arg)
        if kind in ("tensor", "points", "forces"):
            value = fb.tensor_variant(variant, torch.zeros(1) if base is fb.MISSING else base)
        elif kind == "path_in":
            value = fb.path_in_variant(variant, base, case)
        elif kind == "path_out":
            value = fb.path_out_variant(variant, base, case)
        else:
            value = getattr(fb, f"{kind}_variant")(variant, base)
        args[arg] = value
        names += names_for(entry, kind, arg, value)
        valid = valid and kind in ("tensor", "points", "forces") and variant in VALID
    files, before = listing(case), snapshot(args)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            result = call(entry, args, case)
    except Exception as exc:
        verdict = judge_error(exc, names, valid)
        if verdict["verdict"] == "refused" and listing(case) != files:
            verdict = {"verdict": "fail", "detail": f"{verdict['detail']}; but files changed in the case folder"}
    else:
        bad = non_finite(result)
        changed = changed_inputs(args, before)
        verdict = {"verdict": "ok", "detail": ""}
        if bad:
            verdict = {"verdict": "fail", "detail": f"non-finite output: {bad}"}
        elif changed:
            verdict = {"verdict": "fail", "detail": f"inputs changed: {changed}"}
        elif isinstance(result, Path) and not result.exists():
            verdict = {"verdict": "fail", "detail": f"returned {result} but wrote nothing"}
    return check_tmp(tmp, verdict)


def check_tmp(tmp: Path, verdict: dict[str, str]) -> dict[str, str]:
    """Fail a case that left something in the temporary folder (torch's own compile cache aside)."""
    left = sorted(p.name for p in tmp.iterdir() if not p.name.startswith("torchinductor"))
    if left:
        return {"verdict": "fail", "detail": f"{verdict['detail']}; temporary files left behind: {left}"}
    return verdict


def run_case(spec: dict[str, Any], root: Path) -> dict[str, str]:
    from fuzz_cases import CLI

    case, tmp = root / "case", root / "tmp"
    for folder in (case, tmp):
        shutil.rmtree(folder, ignore_errors=True)
        folder.mkdir(parents=True)
    os.chdir(case)
    try:
        if spec["entry"] in CLI:
            from fuzz_cli import run_cli

            return run_cli(spec, case, tmp)
        return run_api(spec, case, tmp)
    except Exception as exc:  # a broken harness, not a library defect: say so
        return {"verdict": "fail", "detail": f"harness error {exc!r}\n{traceback.format_exc()}"}
    finally:
        os.chdir(root)


def main() -> None:
    root = Path(os.environ.get("TORCHFLUIDWARP_FUZZ_ROOT") or tempfile.mkdtemp(prefix="tfw-fuzz-"))
    tempfile.tempdir = str(root / "tmp")
    os.environ["TMPDIR"] = tempfile.tempdir
    if len(sys.argv) > 1:  # reproduce one case
        verdict = run_case(json.loads(sys.argv[1]), root)
        print(verdict["verdict"], verdict["detail"], sep="\n")
        return
    proto = os.fdopen(os.dup(1), "w")
    os.dup2(os.open(os.devnull, os.O_WRONLY), 1)
    sys.stdout = open(os.devnull, "w")  # noqa: SIM115
    import torch

    torch.set_num_threads(1)
    import torchfluidwarp  # noqa: F401  (import once, before the first case's clock starts)

    proto.write(json.dumps({"verdict": "ready", "detail": ""}) + "\n")
    proto.flush()
    for line in sys.stdin:
        verdict = run_case(json.loads(line), root)
        proto.write(json.dumps(verdict) + "\n")
        proto.flush()


if __name__ == "__main__":
    with contextlib.suppress(BrokenPipeError):
        main()
