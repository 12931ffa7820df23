"""Worker side of the fuzz suite: build a case's arguments from its spec and run its entry point.

Only ``fuzz_worker.py`` imports this module (it imports torch and the library); see ``fuzz_cases.py``.
"""

from __future__ import annotations

import json
import math
import struct
import zlib
from collections.abc import Callable
from pathlib import Path
from typing import Any

import torch
from torch import Tensor

MISSING = object()  # the argument is left out of the call


# ---------------------------------------------------------------------------------------------- variants


def tensor_variant(v: str, x: Tensor) -> Any:
    simple = {"none": None, "str": "x", "bool": True, "int": 3, "complex": 1 + 2j, "scalar": torch.tensor(0.5)}
    if v in simple:
        return simple[v]
    if v == "list":
        return x.tolist()
    dtypes = {"int64": torch.int64, "complex64": torch.complex64, "float16": torch.float16,
              "bfloat16": torch.bfloat16, "float64": torch.float64}  # fmt: skip
    if v in dtypes:
        return x.to(dtypes[v])
    if v == "booldtype":
        return x > x.mean() if x.numel() else x.bool()
    if v == "drop_dim":  # an empty first dimension has no x[0]: sum it away instead (zeros of the rest)
        return (x[0] if x.shape[0] else x.sum(0)) if x.ndim else x
    if v == "add_dim":
        return x.unsqueeze(-1)
    if v == "zero_first":
        return x[:0] if x.ndim else x
    if v == "zero_last":
        return x[..., :0] if x.ndim else x
    if v in ("nan", "inf", "neg_inf"):
        y = x.clone()
        if y.numel():
            y.view(-1)[y.numel() // 2] = {"nan": math.nan, "inf": math.inf, "neg_inf": -math.inf}[v]
        return y
    scale = {"huge": 1e30, "big": 1e7, "large": 1e4, "tiny": 1e-30, "negate": -1.0}
    if v in scale:
        return x * scale[v]
    if v == "batch_plus":
        return torch.cat([x, x]) if x.ndim else x
    if v == "requires_grad":
        return x.clone().requires_grad_(True) if x.is_floating_point() else x
    if v == "noncontig":
        return x.transpose(-1, -2).contiguous().transpose(-1, -2) if x.ndim >= 2 else x
    if v == "identical":
        return x[..., :1, :].expand_as(x).clone()
    if v == "collinear":
        y = x.clone()
        y[..., 1] = y[..., 0]
        return y
    if v == "fewer":
        return x[..., :-1, :]
    if v == "outside":
        return x + 1000.0
    if v == "force_str":
        return "x"
    if v == "force_callable_bad":
        return lambda *args: "x"
    raise KeyError(v)


def number_variant(v: str, base: Any) -> Any:
    table = {"none": None, "str": "0.1", "bool": True, "complex": 1j, "nan": math.nan, "inf": math.inf,
             "neg_inf": -math.inf, "negative": -1.0, "zero": 0.0, "huge": 1e30, "tiny": 1e-300, "bigint": 10**30,
             "float_half": 0.5, "list": [0.1]}  # fmt: skip
    if v == "tensor0d":
        return torch.tensor(0.1)
    return table[v]


def int_variant(v: str, base: Any) -> Any:
    table = {"none": None, "str": "3", "bool": True, "complex": 1j, "nan": math.nan, "inf": math.inf,
             "negative": -1, "zero": 0, "bigint": 10**9, "float_half": 1.5, "float_int": 2.0, "list": [2]}  # fmt: skip
    return table[v]


def size_variant(v: str, base: Any) -> Any:
    table = {"none": None, "str": "8", "bool": True, "zero": 0, "negative": -4, "pair_zero": (0, 8), "one": (8,),
             "triple": (8, 8, 8), "float_pair": (8.5, 8.0), "bool_pair": (True, 8), "huge": 10**6}  # fmt: skip
    return table[v]


def fraction_variant(v: str, base: Any) -> Any:
    return {"none": None, "str": "yes", "two": 2, "negative": -0.5, "nan": math.nan, "half": 0.5, "true": True,
            "complex": 1j}[v]  # fmt: skip


def choice_variant(v: str, base: Any) -> Any:
    return {"none": None, "str": "x", "int": 3, "empty": "", "upper": str(base).upper()}[v]


def dtype_variant(v: str, base: Any) -> Any:
    return {"str": "float32", "complex64": torch.complex64, "int64": torch.int64, "none": None,
            "float16": torch.float16, "python_float": float, "bool": torch.bool}[v]  # fmt: skip


def range_variant(v: str, base: Any) -> Any:
    lo, hi = base
    return {"none": None, "str": "x", "nan": (math.nan, hi), "inf": (lo, math.inf), "negative": (-1, hi),
            "reversed": (hi + 1, lo), "huge": (10**9, 10**9), "zero": 0, "triple": (lo, hi, hi),
            "complex": 1j}[v]  # fmt: skip


def generator_variant(v: str, base: Any) -> Any:
    return {"str": "x", "int": 3}[v]


def module_variant(v: str, base: Any) -> Any:
    """Something that is not a force module where one is expected."""
    return {"str": "x", "int": 3, "tensor": torch.zeros(1, 2, 2, 4, 4), "callable": lambda *args: "x"}[v]


# ------------------------------------------------------------------------------------------------- files


def png_bytes(h: int = 8, w: int = 8, seed: int = 0) -> bytes:
    import io

    from PIL import Image

    g = torch.Generator().manual_seed(seed)
    arr = (torch.rand(h, w, 3, generator=g) * 255).to(torch.uint8).numpy()
    buf = io.BytesIO()
    Image.fromarray(arr).save(buf, format="PNG")
    return buf.getvalue()


def bomb_png(w: int = 60000, h: int = 60000) -> bytes:
    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)

    ihdr = struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0)
    idat = zlib.compress(b"\x00" * 64)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", idat) + chunk(b"IEND", b"")


def points_json(points: Tensor) -> str:
    return json.dumps(points.tolist())


FILE_CONTENT: dict[str, Callable[[], bytes]] = {
    "empty_file": lambda: b"",
    "garbage": lambda: b"\x00\xffnot a file \x01" * 8,
    "truncated": lambda: png_bytes()[:40],
    "bomb": bomb_png,
    "nested_json": lambda: b"[" * 5000 + b"]" * 5000,
    "huge_numbers": lambda: b"[[1e400, 2], [3, 10" + b"0" * 400 + b"], [5, 6]]",
    "nan_json": lambda: b"[[NaN, 1.0], [2.0, 3.0], [4.0, 5.0]]",
    "one_column": lambda: b"1\n2\n3\n",
}


def path_in_variant(v: str, base: Path, folder: Path) -> Any:
    """A broken input file (or a bad path) in place of ``base``, a valid file."""
    if v in ("none", "int", "empty_str"):
        return {"none": None, "int": 3, "empty_str": ""}[v]
    if v == "missing":
        return folder / f"missing{base.suffix}"
    if v == "folder":
        (folder / "a_folder").mkdir(exist_ok=True)
        return folder / "a_folder"
    if v == "wrong_suffix":
        path = folder / "points.txt"
        path.write_bytes(base.read_bytes())
        return path
    if v == "bytes_path":
        return bytes(base)
    suffix = ".json" if v in ("nested_json", "huge_numbers", "nan_json") else base.suffix
    suffix = ".csv" if v == "one_column" else suffix
    path = folder / f"broken_{v}{suffix}"
    path.write_bytes(FILE_CONTENT[v]())
    return path


def path_out_variant(v: str, base: Path, folder: Path) -> Any:
    if v in ("none", "int", "empty_str", "dot"):
        return {"none": None, "int": 3, "empty_str": "", "dot": "."}[v]
    if v == "folder":
        (folder / "out_folder").mkdir(exist_ok=True)
        return folder / "out_folder"
    if v == "unknown_suffix":
        return folder / "out.xyz"
    if v == "missing_parent":
        return folder / "a" / "b" / base.name
    if v == "existing":
        base.write_bytes(b"keep me")
        return base
    raise KeyError(v)


def bytes_variant(v: str, base: bytes) -> Any:
    if v in ("none", "str"):
        return {"none": None, "str": "x"}[v]
    return FILE_CONTENT[{"empty": "empty_file"}.get(v, v)]()
