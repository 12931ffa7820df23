"""The fuzz cases: which entry points there are, which arguments each takes, and how a case is built and judged.

A case is a JSON-able spec, ``{"entry": ..., "dims": {...}, "perturb": [[arg, variant], ...], "seed": int}``:
the entry point's valid base call (small: images 8..24 px, grids 4..8 cells, 1..3 steps, one or two L-BFGS
iterations), with up to two of its arguments replaced by a variant from the input families of issue #19
(wrong types, dtypes and shapes, empty and zero-size tensors, NaN/inf/huge values, broken, huge and malformed
files). The parent process draws specs with Hypothesis (:func:`specs`); the worker (``fuzz_worker.py``) builds
and runs them (:func:`run_case`) and judges the outcome:

* a result: every float tensor in it is finite, and the inputs are unchanged;
* an error: a ``ValueError``, ``TypeError``, ``FlowBlewUp`` or ``FileNotFoundError``-style ``OSError`` whose message
  names a perturbed argument (a case with only valid variants must succeed);
* for the CLI: exit 0 with the output written, or exit 2 (3 for a blown-up flow) with one line on stderr, no
  traceback and no output;
* either way no file left behind: nothing new in the case's folder after a refusal, nothing in the temporary
  folder after any case.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

# ----------------------------------------------------------------------------------------------------------
# argument kinds and their variants (the input families)

TENSOR = [
    "none", "str", "bool", "int", "complex", "list",
    "int64", "booldtype", "complex64", "float16", "bfloat16", "float64",
    "drop_dim", "add_dim", "zero_first", "zero_last", "scalar",
    "nan", "inf", "neg_inf", "huge", "big", "large", "tiny", "negate", "batch_plus",
    "requires_grad", "noncontig",
]  # fmt: skip
POINTS = [*TENSOR, "identical", "collinear", "fewer", "outside"]
NUMBER = ["none", "str", "bool", "complex", "nan", "inf", "neg_inf", "negative", "zero", "huge", "tiny", "bigint",
          "float_half", "tensor0d", "list"]  # fmt: skip
INT = ["none", "str", "bool", "complex", "nan", "inf", "negative", "zero", "bigint", "float_half", "float_int", "list"]
SIZE = ["none", "str", "bool", "zero", "negative", "pair_zero", "one", "triple", "float_pair", "bool_pair", "huge"]
FRACTION = ["none", "str", "two", "negative", "nan", "half", "true", "complex"]
CHOICE = ["none", "str", "int", "empty", "upper"]
DTYPE = ["str", "complex64", "int64", "none", "float16", "python_float", "bool"]
PATH_IN = ["none", "int", "empty_str", "missing", "folder", "empty_file", "garbage", "truncated", "bomb",
           "nested_json", "huge_numbers", "nan_json", "one_column", "wrong_suffix", "bytes_path"]  # fmt: skip
PATH_OUT = ["none", "int", "empty_str", "dot", "folder", "unknown_suffix", "missing_parent", "existing"]
BYTES = ["none", "str", "empty", "garbage", "truncated", "bomb"]
RANGE = ["none", "str", "nan", "inf", "negative", "reversed", "huge", "zero", "triple", "complex"]
GENERATOR = ["str", "int"]
MODULE = ["str", "int", "tensor", "callable"]
FORCES = [*TENSOR, "force_str", "force_callable_bad"]

VARIANTS = {
    "tensor": TENSOR, "points": POINTS, "forces": FORCES, "number": NUMBER, "int": INT, "size": SIZE,
    "fraction": FRACTION, "choice": CHOICE, "dtype": DTYPE, "path_in": PATH_IN, "path_out": PATH_OUT,
    "bytes": BYTES, "range": RANGE, "generator": GENERATOR, "module": MODULE, "cli": [],
}  # fmt: skip
VALID = {"float16", "bfloat16", "float64", "requires_grad", "noncontig"}
"""Tensor variants that the dtype policy accepts: a case whose variants are all of these must succeed."""

CLI_VALUES = ["", "x", "nan", "inf", "-inf", "-1", "0", "0.5", "1e30", "1e-300", "1000000000", "3", "1,2", "ä"]
CLI_FILES = ["missing", "folder", "empty_file", "garbage", "truncated", "bomb", "nested_json", "huge_numbers",
             "nan_json", "identical", "fewer"]  # fmt: skip

# ----------------------------------------------------------------------------------------------------------
# the entry points: argument -> kind (the parent draws from these; the worker builds the calls)

ENTRIES: dict[str, dict[str, str]] = {
    "FluidSimulator": {"grid": "size", "dt": "number", "viscosity": "number", "compressible": "fraction",
                       "forces": "forces", "points": "points", "velocity": "tensor"},
    "FluidWarp.forward": {"grid": "size", "steps": "int", "dt": "number", "viscosity": "number",
                          "compressible": "fraction", "mode": "choice", "image": "tensor", "forces": "forces"},
    "FluidWarp.iter_frames": {"image": "tensor", "forces": "forces", "steps": "int", "dt": "number"},
    "FluidWarp.carry_points": {"points": "points", "forces": "forces", "size": "size", "dt": "number"},
    "FluidWarp.maps": {"forces": "forces", "size": "size", "steps": "int"},
    "warp_image": {"image": "tensor", "coords": "tensor", "mode": "choice"},
    "jacobian_determinant": {"coords": "tensor"},
    "fit_keyframes": {"source": "points", "target": "points", "image_size": "size", "grid": "size", "steps": "int",
                      "control": "size", "dt": "number", "regularization": "number", "smoothness": "number",
                      "max_iter": "int", "tolerance": "number", "compressible": "fraction", "dtype": "dtype",
                      "weights": "tensor", "forces": "module", "method": "choice"},
    "fit_images": {"source": "tensor", "target": "tensor", "loss": "choice", "grid": "size", "steps": "int",
                   "control": "size", "max_iter": "int", "compressible": "fraction", "dtype": "dtype",
                   "regularization": "number", "point_weight": "number", "viscosity": "number"},
    "morph": {"image_a": "tensor", "image_b": "tensor", "points_a": "points", "points_b": "points",
              "frames": "int", "method": "choice", "grid": "size", "steps": "int", "control": "size",
              "inverse": "choice", "blend": "choice", "compressible": "fraction", "max_iter": "int",
              "margin": "number", "smoothness": "number", "feather": "number", "align": "choice",
              "tolerance": "number", "warm_start": "choice"},
    "RandomFluidWarp": {"image": "tensor", "mask": "tensor", "boxes": "tensor", "count": "range",
                        "strength": "range", "radius": "range", "steps": "range", "grid": "size", "dt": "number",
                        "generator": "generator"},
    "random_fluid_warp": {"image": "tensor", "keypoints": "points", "masks": "tensor", "boxes": "tensor",
                          "count": "range", "strength": "range", "radius": "range", "steps": "range",
                          "grid": "size", "viscosity": "number", "edge_points": "int", "max_retries": "int"},
    "FluidWarpAugment": {"image": "tensor", "keypoints": "points", "strength": "range", "radius": "range",
                         "dt": "number", "generator": "generator"},
    "estimate_alignment": {"points_a": "points", "points_b": "points", "kind": "choice"},
    "read_image": {"path": "path_in", "channels": "int", "dtype": "dtype", "max_pixels": "int"},
    "read_image_bytes": {"data": "bytes", "channels": "int", "max_pixels": "int"},
    "write_image": {"path": "path_out", "image": "tensor"},
    "resize_image": {"image": "tensor", "size": "size", "max_memory": "number"},
    "shrink_image": {"image": "tensor", "longest": "int"},
    "read_points": {"path": "path_in", "dtype": "dtype", "max_bytes": "int"},
    "write_points": {"path": "path_out", "points": "points"},
    "write_animation": {"path": "path_out", "frames": "tensor", "fps": "number", "loop": "int",
                        "overwrite": "fraction"},
    "encode_animation": {"frames": "tensor", "fmt": "choice", "fps": "number", "loop": "int"},
}  # fmt: skip
API = [e for e in ENTRIES if not e.startswith(("read_", "write_", "resize_", "shrink_", "encode_"))]
IO = [e for e in ENTRIES if e not in API]

CLI: dict[str, dict[str, str]] = {
    "animate": {"IMAGE": "file_image", "-o": "out", "--config": "file_config", "--brush": "value",
                "--stiff": "value", "--viscosity": "value", "--grid": "value", "--steps": "value", "--dt": "value",
                "--fps": "value", "--max-size": "value", "--unknown": "value"},
    "morph": {"A": "file_image", "B": "file_image", "--points-a": "file_points", "--points-b": "file_points",
              "-o": "out", "--frames": "value", "--fps": "value", "--steps": "value", "--control": "value",
              "--method": "value", "--align": "value", "--inverse": "value", "--blend": "value", "--grid": "value",
              "--compressible": "value", "--smoothness": "value", "--max-iter": "value", "--unknown": "value"},
    "demo": {"-o": "out", "--frames": "value", "--fps": "value", "--steps": "value", "--grid": "value",
             "--max-iter": "value", "--method": "value", "--compressible": "value"},
    "studio": {"--port": "value", "--unknown": "value", "--help": "value"},
}  # fmt: skip
OUTS = ["", ".", "folder", "out.xyz", "missing/deeper/out.gif", "existing.gif", "frames/", "out.gif"]


def specs() -> Any:
    """Hypothesis strategies: ``(api, io, cli)`` specs."""
    from hypothesis import strategies as st

    dims = st.fixed_dictionaries(
        {
            "B": st.integers(1, 2),
            "C": st.sampled_from([1, 3]),
            "H": st.integers(8, 24),
            "W": st.integers(8, 24),
            "g": st.integers(4, 8),
            "T": st.integers(1, 3),
            "M": st.integers(3, 5),
        }  # fmt: skip
    )

    def entry_specs(names: list[str], table: dict[str, dict[str, str]], values: Callable[[str], list[str]]) -> Any:
        def one(entry: str) -> Any:
            args = sorted(table[entry])
            perturb = st.sampled_from(args).flatmap(
                lambda a: st.tuples(st.just(a), st.sampled_from(values(table[entry][a]))).map(list)
            )
            return st.fixed_dictionaries(
                {
                    "entry": st.just(entry),
                    "dims": dims,
                    "perturb": st.lists(perturb, max_size=2, unique_by=lambda p: p[0]),
                    "seed": st.integers(0, 2**31 - 1),
                }
            )

        return st.sampled_from(names).flatmap(one)

    def cli_values(kind: str) -> list[str]:
        return {"file_image": CLI_FILES, "file_points": CLI_FILES, "file_config": CLI_FILES, "out": OUTS}.get(
            kind, CLI_VALUES
        )

    return (
        entry_specs(API, ENTRIES, lambda k: VARIANTS[k]),
        entry_specs(IO, ENTRIES, lambda k: VARIANTS[k]),
        entry_specs(sorted(CLI), CLI, cli_values),
    )
