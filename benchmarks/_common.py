"""Helpers every benchmark script shares, written once: the command line, what machine the figures come from and
how busy it was, timing loops, peak memory, tables, results written atomically, fresh-process runs, and the
sample problems (the paper's keyframe instances, the stirring brushes of the warp benchmarks).

The scripts run as ``python benchmarks/<script>.py``, so this module is importable as ``_common``. They use only
the public API of ``torchfluidwarp``.
"""

from __future__ import annotations

import argparse
import datetime
import hashlib
import json
import math
import os
import pathlib
import platform
import shlex
import statistics
import subprocess
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import torch
from torch import Tensor

# ----------------------------------------------------------------------------------------------- the machine


def machine() -> dict[str, Any]:
    """What the figures were measured on."""
    model = platform.processor()
    try:
        with open("/proc/cpuinfo") as f:
            info = dict(line.split(":", 1) for line in f.read().split("\n\n")[0].splitlines() if ":" in line)
        info = {k.strip(): v.strip() for k, v in info.items()}
        # one brand name covers several generations (EPYC family 25 is model 1 and model 17): name the model
        model = f"{info['model name']} (family {info.get('cpu family', '?')}, model {info.get('model', '?')})"
    except (OSError, KeyError):
        pass
    return {
        "cpu": model,
        "cpu_count": os.cpu_count(),
        "torch_threads": torch.get_num_threads(),
        "python": platform.python_version(),
        "torch": torch.__version__,
        "platform": platform.platform(),
        "date": datetime.datetime.now().isoformat(timespec="seconds"),
    }


def machine_load() -> dict[str, Any]:
    """Load average and, where the kernel has it, CPU pressure (PSI ``some avg60``: share of time that some task
    waited for a CPU): how busy the shared machine was."""
    out: dict[str, Any] = {"loadavg": os.getloadavg()}
    try:
        with open("/proc/pressure/cpu") as f:
            fields = dict(kv.split("=") for kv in f.readline().split()[1:])
        out["cpu_pressure_some_avg60"] = float(fields["avg60"])
    except (OSError, KeyError, ValueError):
        pass
    return out


def describe_load(load: dict[str, Any]) -> str:
    text = "load average " + " ".join(f"{x:.2f}" for x in load["loadavg"])
    if "cpu_pressure_some_avg60" in load:
        text += f", CPU pressure {load['cpu_pressure_some_avg60']:.0f}% (some, avg60)"
    return text


def source_fingerprint() -> str:
    """sha256 (12 hex digits) of the installed ``torchfluidwarp`` sources: ties the figures to a code state."""
    import torchfluidwarp

    root = pathlib.Path(torchfluidwarp.__file__).parent
    digest = hashlib.sha256()
    for path in sorted(root.rglob("*.py")):
        digest.update(str(path.relative_to(root)).encode())
        digest.update(path.read_bytes())
    return digest.hexdigest()[:12]


def status_kib(field: str) -> float:
    """A ``/proc/self/status`` memory field (``VmRSS``, ``VmHWM``) in KiB."""
    with open("/proc/self/status") as f:
        return float(next(line.split()[1] for line in f if line.startswith(field + ":")))


def reset_peak() -> bool:
    """Return freed heap to the OS and reset this process's ``VmHWM`` to its current RSS (Linux >= 4.0).

    ``ru_maxrss`` cannot be reset, and a process started by ``exec`` inherits its parent's peak RSS into
    it, so a child's ``ru_maxrss`` never reads below the parent's RSS at launch. ``VmHWM`` after this reset is
    the peak of this process alone. Returns whether the reset worked.
    """
    try:
        import ctypes

        ctypes.CDLL("libc.so.6").malloc_trim(0)
    except (OSError, AttributeError):
        pass
    try:
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")
        return True
    except OSError:
        return False


def peak_mib(base_kib: float | None = None) -> float:
    """Without ``base_kib``: reset ``VmHWM`` (:func:`reset_peak`) and return the RSS in KiB, the baseline. With it:
    the peak RSS growth since that baseline, MiB (NaN where the reset failed, ``base_kib`` 0)."""
    if base_kib is None:
        return status_kib("VmRSS") if reset_peak() else 0.0
    return (status_kib("VmHWM") - base_kib) / 1024 if base_kib else math.nan


# ----------------------------------------------------------------------------------------------- command line


def parser(
    doc: str | None, quick: str | None = None, threads: int | None = 1, child: bool = False
) -> argparse.ArgumentParser:
    """An argument parser with the options every script shares: ``--json PATH``, ``--threads`` (unless
    ``threads`` is ``False``), given its help text ``--quick`` (a smoke run, not for figures), and with ``child``
    the hidden ``--_child SPEC`` of :func:`run_child`."""
    p = argparse.ArgumentParser(
        description=(doc or "").split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("--json", metavar="PATH", help="also write the results as JSON to PATH")
    if threads is not False:
        p.add_argument(
            "--threads",
            type=int,
            default=threads,
            help=f"torch CPU threads (default {threads or 'torch'}; "
            "on a small shared machine, multi-threaded kernels stall while another process holds a core)",
        )
    if quick:
        p.add_argument("--quick", action="store_true", help=f"smoke run, not for figures: {quick}")
    if child:
        p.add_argument("--_child", help=argparse.SUPPRESS)
    return p


def start(name: str, threads: int | None = None, note: str = "", argv: list[str] | None = None) -> dict[str, Any]:
    """Set torch's threads, print the machine, the sources' digest, the load and the command (``argv`` for a
    ``main(argv)`` called from Python); returns the run's ``info``."""
    if threads:
        torch.set_num_threads(threads)
    info = machine()
    info["load_start"] = machine_load()
    info["sources_sha256"] = source_fingerprint()
    print(
        f"{name}: {info['cpu']}, {info['cpu_count']} CPUs, torch {info['torch']} with {info['torch_threads']} "
        f"thread(s), Python {info['python']}, {info['date']}{note}",
        flush=True,
    )
    print(f"torchfluidwarp sources sha256 {info['sources_sha256']}; at the start: {describe_load(info['load_start'])}")
    print(f"command: {shlex.join(sys.argv if argv is None else [name, *argv])}")
    info["_t0"] = time.perf_counter()
    return info


def finish(info: dict[str, Any], result: dict[str, Any], path: str | None) -> None:
    """Print the total time and the load at the end, warn if the sources changed, write ``result`` to ``path``."""
    total = time.perf_counter() - info.pop("_t0")
    info["load_end"] = machine_load()
    print(f"\ntotal {total:.0f} s; at the end: {describe_load(info['load_end'])}")
    if source_fingerprint() != info["sources_sha256"]:
        info["sources_changed"] = True
        print("WARNING: the torchfluidwarp sources changed during the run (subprocesses imported the new code)")
    if path:
        write_json(path, {"machine": info, **result, "total_s": total})


def log(msg: str) -> None:
    """Progress, on stderr (the tables go to stdout)."""
    print(msg, file=sys.stderr, flush=True)


# ----------------------------------------------------------------------------------------------- timing


def median_ms(seconds: Any) -> float:
    return statistics.median(seconds) * 1e3


def interleaved(
    cases: dict[str, Callable[[], Any]], repeats: int, warmup: int = 1, sync: Callable[[], Any] | None = None
) -> dict[str, list[tuple[float, float]]]:
    """Run every case ``warmup`` times, then ``repeats`` rounds over the cases in turn (so that load from other
    processes falls on all alike): ``{case: [(wall s, this process's CPU s), ...]}``. ``sync`` runs before every
    clock reading (``torch.cuda.synchronize`` on a GPU)."""
    for _ in range(warmup):
        for fn in cases.values():
            fn()
    out: dict[str, list[tuple[float, float]]] = {k: [] for k in cases}
    for _ in range(repeats):
        for k, fn in cases.items():
            if sync:
                sync()
            t0, c0 = time.perf_counter(), time.process_time()
            fn()
            if sync:
                sync()
            out[k].append((time.perf_counter() - t0, time.process_time() - c0))
    return out


def medians_ms(times: dict[str, list[tuple[float, float]]], cpu: bool = False) -> dict[str, float]:
    """Median wall (or CPU) ms of each case of :func:`interleaved`."""
    return {k: median_ms(t[1 if cpu else 0] for t in v) for k, v in times.items()}


# ----------------------------------------------------------------------------------------------- output


def table(headers: list[str], rows: list[list[str]], markdown: bool = False) -> str:
    """Right-aligned columns; ``markdown``: a Markdown table, its first column left-aligned."""
    if markdown:
        rule = "|---|" + "---:|" * (len(headers) - 1)
        return "\n".join(["| " + " | ".join(cells) + " |" for cells in [headers]] + [rule] +
                         ["| " + " | ".join(cells) + " |" for cells in rows])  # fmt: skip
    widths = [max(len(h), *(len(r[i]) for r in rows)) for i, h in enumerate(headers)]
    line = lambda cells: "  ".join(c.rjust(w) for c, w in zip(cells, widths))
    return "\n".join([line(headers), line(["-" * w for w in widths]), *map(line, rows)])


def rows_table(rows: list[dict[str, Any]], spec: str, markdown: bool = False) -> str:
    """A table of dict rows. ``spec`` lists the columns, ``|``-separated: a header, then the cell as a
    ``str.format`` template over the row (``"fit s {seconds:.2f} | evals {evaluations}"``)."""
    cols = [c.split("{", 1) for c in spec.split("|")]
    heads, cells = [h.strip() for h, _ in cols], ["{" + t.strip() for _, t in cols]
    return table(heads, [[c.format(**r) for c in cells] for r in rows], markdown)


def verdict(ok: bool) -> str:
    return "met" if ok else "NOT met"


def yes(b: bool) -> str:
    return "yes" if b else "no"


def fmt(x: float | None, digits: int = 2) -> str:
    """``x`` with ``digits`` decimals; ``"—"`` for ``None`` or NaN (a figure that could not be taken)."""
    return "—" if x is None or x != x else f"{x:.{digits}f}"


def write_json(path: str, result: Any, default: Any = None) -> None:
    """Write ``result`` as indented JSON to ``path`` through a temporary file, so a crash never leaves half a file."""
    tmp = path + ".tmp"
    with open(tmp, "w") as f:
        json.dump(result, f, indent=2, default=default if default is not None else str)
    os.replace(tmp, path)


def pyplot() -> Any:
    """``matplotlib.pyplot`` on the Agg backend (files only, no display)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def save_figure(fig: Any, path: str) -> None:
    """Save a matplotlib figure to ``path`` through a temporary file, and close it."""
    tmp = path + ".tmp.png"
    fig.savefig(tmp)
    pyplot().close(fig)
    os.replace(tmp, path)


# ----------------------------------------------------------------------------------------------- fresh processes


def run_child(script: str, spec: dict[str, Any]) -> dict[str, Any]:
    """Run ``script --_child SPEC`` in a fresh process; its last stdout line is its JSON result."""
    proc = subprocess.run([sys.executable, script, "--_child", json.dumps(spec)], capture_output=True, text=True)
    if proc.returncode != 0:
        return {**spec, "failed": True, "returncode": proc.returncode, "stderr_tail": proc.stderr[-2000:]}
    return json.loads(proc.stdout.strip().splitlines()[-1])


def as_child(args: argparse.Namespace, fn: Callable[[dict[str, Any]], dict[str, Any]]) -> bool:
    """In a process :func:`run_child` started (``parser(..., child=True)``): print ``fn(spec)`` as its JSON result
    and return ``True``; in any other, ``False``."""
    if not args._child:
        return False
    print(json.dumps(fn(json.loads(args._child))))
    return True


# ----------------------------------------------------------------------------------------------- sample problems

FRAME = (64, 64)  # the keyframe instances' image size, pixels
MARGIN = 6.0  # px: sources at least this far from the walls
SPACING = 6.0  # px: sources at least this far apart
DISPLACEMENT = (5.0, 10.0)  # px


@dataclass
class Instance:
    """One keyframe problem: ``source`` and ``target`` ``(M, 2)`` in pixels of a :data:`FRAME` image."""

    name: str
    kind: str  # "flow" or "random"
    seed: int
    source: list[list[float]]
    target: list[list[float]]
    brush_scale: float | None = None
    attempts: int = 1

    def tensors(self, dtype: torch.dtype = torch.float64) -> tuple[Tensor, Tensor]:
        return torch.tensor(self.source, dtype=dtype), torch.tensor(self.target, dtype=dtype)

    def describe(self) -> dict[str, float]:
        """Least and largest displacement, least spacing of the sources, least distance of a target to a wall."""
        src, tgt = self.tensors()
        d = (tgt - src).norm(dim=-1)
        H, W = FRAME
        walls = torch.stack([tgt[:, 0] + 0.5, W - 0.5 - tgt[:, 0], tgt[:, 1] + 0.5, H - 0.5 - tgt[:, 1]])
        spacing = torch.cdist(src, src) + torch.eye(len(src), dtype=src.dtype) * 1e9
        return dict(
            min_disp=float(d.min()),
            max_disp=float(d.max()),
            min_spacing=float(spacing.min()),
            min_wall=float(walls.min()),
        )


def _pick(points: Tensor, ok: Tensor, m: int, gen: torch.Generator) -> list[int]:
    """Indices of up to ``m`` points with ``ok``, visited in random order, at least ``SPACING`` apart."""
    chosen: list[int] = []
    for i in torch.randperm(len(points), generator=gen).tolist():
        if ok[i] and all(float((points[i] - points[j]).norm()) >= SPACING for j in chosen):
            chosen.append(i)
            if len(chosen) == m:
                break
    return chosen


def flow_instance(seed: int, m: int = 14, grid: tuple[int, int] = (64, 64), steps: int = 10) -> Instance:
    """The paper's keyframe problem with targets a flow reaches: four random steady Gaussian ``Brushes`` drive
    the library's own ``FluidWarp`` (float64); their strength is scaled by bisection so that 60% of the candidate
    sources (a jittered 1-px lattice, :data:`MARGIN` from the walls) move less than 7.5 px; ``m`` sources are
    picked in random order among those that move 5 to 10 px, :data:`SPACING` apart. The targets are where the
    flow carries them."""
    from torchfluidwarp.warp import Brushes, FluidWarp

    H, W = FRAME
    lo, hi = DISPLACEMENT
    f64 = torch.float64
    warp = FluidWarp(grid, steps, image_size=FRAME).double()
    for attempt in range(20):
        gen = torch.Generator().manual_seed(10_000 * seed + attempt)
        span = torch.tensor([W - 1 - 2 * MARGIN, H - 1 - 2 * MARGIN], dtype=f64)
        centers = MARGIN + torch.rand(4, 2, generator=gen, dtype=f64) * span
        angle = torch.rand(4, generator=gen, dtype=f64) * 2 * math.pi
        radius = 8.0 + 8.0 * torch.rand(4, generator=gen, dtype=f64)
        base = 0.5 + torch.rand(4, generator=gen, dtype=f64)
        brushes = Brushes(centers, torch.stack([angle.cos(), angle.sin()], -1), radius=radius, amplitude=base).double()
        axes = torch.arange(MARGIN, H - MARGIN, dtype=f64), torch.arange(MARGIN, W - MARGIN, dtype=f64)
        ys, xs = torch.meshgrid(*axes, indexing="ij")
        cand = torch.stack([xs, ys], -1).reshape(-1, 2)
        cand = (cand + torch.rand(cand.shape, generator=gen, dtype=f64) - 0.5).clamp(
            torch.tensor([MARGIN, MARGIN], dtype=f64), torch.tensor([W - 1 - MARGIN, H - 1 - MARGIN], dtype=f64)
        )

        def carry(scale: float) -> Tensor:
            with torch.no_grad():
                brushes.amplitude.copy_(base * scale)
                return warp.carry_points(cand[None], brushes)[0, -1]  # (N, 2) pixels

        s_lo, s_hi = 0.0, 4.0
        for _ in range(16):  # the displacement grows about linearly with the strength
            s = 0.5 * (s_lo + s_hi)
            if float((carry(s) - cand).norm(dim=-1).quantile(0.6)) < 0.5 * (lo + hi):
                s_lo = s
            else:
                s_hi = s
        end = carry(s_hi)
        d = (end - cand).norm(dim=-1)
        chosen = _pick(cand, (d >= lo) & (d <= hi), m, gen)
        if len(chosen) == m:
            src, tgt = cand[chosen].tolist(), end[chosen].tolist()
            return Instance(f"flow seed {seed}", "flow", seed, src, tgt, s_hi, attempt + 1)
    raise RuntimeError(f"no flow instance with {m} points for seed {seed} in 20 attempts")


def random_instance(seed: int, m: int = 14) -> Instance:
    """Sources spread as in :func:`flow_instance`; each target 5 to 10 px away in a random direction, 1 px inside
    the frame. A flow need not reach them (nearby points may be asked to cross)."""
    H, W = FRAME
    lo, hi = DISPLACEMENT
    gen = torch.Generator().manual_seed(seed)
    rand = lambda: float(torch.rand((), generator=gen, dtype=torch.float64))
    span = torch.tensor([W - 1 - 2 * MARGIN, H - 1 - 2 * MARGIN], dtype=torch.float64)
    src: list[Tensor] = []
    while len(src) < m:
        p = MARGIN + torch.rand(2, generator=gen, dtype=torch.float64) * span
        if all(float((p - q).norm()) >= SPACING for q in src):
            src.append(p)
    tgt: list[Tensor] = []
    for p in src:
        while True:
            a, r = rand() * 2 * math.pi, lo + rand() * (hi - lo)
            q = p + r * torch.tensor([math.cos(a), math.sin(a)], dtype=torch.float64)
            if 0.5 <= float(q[0]) <= W - 1.5 and 0.5 <= float(q[1]) <= H - 1.5:
                tgt.append(q)
                break
    return Instance(f"random seed {seed}", "random", seed, torch.stack(src).tolist(), torch.stack(tgt).tolist())


FLUID = (64, 64)  # the warp benchmarks' fluid grid


def make_brushes(size: tuple[int, int]) -> Any:
    """Three oscillating ``Brushes`` (period 20 steps, radius 12% of the shorter side) at fixed fractions of an
    image of ``size``: the same flow, in fluid cells, for any size (0.15 cells per time unit^2 on :data:`FLUID`, a
    peak velocity of about 0.5 cells per step)."""
    from torchfluidwarp.warp import Brushes

    H, W = size
    centers = [[0.30 * W, 0.35 * H], [0.70 * W, 0.55 * H], [0.45 * W, 0.80 * H]]
    directions = [[1.0, 0.3], [-0.2, 1.0], [1.0, -1.0]]
    amplitude = 0.15 * H / FLUID[0]
    phase = [0.0, 2.1, 4.2]
    return Brushes(centers, directions, radius=0.12 * min(H, W), amplitude=amplitude, frequency=0.05, phase=phase)


def stirred(size: tuple[int, int], steps: int, device: Any = "cpu") -> tuple[Any, Any, Tensor]:
    """The warp benchmarks' set-up for an image of ``size``: ``FluidWarp`` on the :data:`FLUID` grid over ``steps``
    (``dt = 1``), :func:`make_brushes` and a smooth random RGB float32 image ``(1, 3, H, W)`` in ``[0, 1]`` (content
    does not change the cost), on ``device``."""
    from torchfluidwarp.warp import FluidWarp

    warp = FluidWarp(FLUID, steps=steps, dt=1.0).to(device)
    coarse = torch.rand(1, 3, 16, 16, generator=torch.Generator().manual_seed(1234))
    image = torch.nn.functional.interpolate(coarse, size=size, mode="bilinear", align_corners=False)
    return warp, make_brushes(size).to(device), image.to(device)


# ----------------------------------------------------------------------------------------------- morph


def morph_settings(spec: dict[str, Any] | None = None) -> Any:
    """Typed morph settings from a JSON-like dict: ``"method"`` (``"natural"``, the default, or ``"paper"``) picks
    the class (:data:`torchfluidwarp.morph.settings.METHODS`), the other keys are its fields
    (``{"method": "paper", "grid": 32, "max_iter": 20}``); ``"dense"`` may be a dict of
    :class:`~torchfluidwarp.correspond.halfway.HalfwaySettings` fields."""
    from torchfluidwarp.correspond.halfway import HalfwaySettings
    from torchfluidwarp.morph.settings import METHODS

    spec = dict(spec or {})
    if isinstance(spec.get("dense"), dict):  # {"dense": {"levels": [64, 128], ...}}: the pixels' help
        dense = {k: tuple(v) if isinstance(v, list) else v for k, v in spec["dense"].items()}
        spec["dense"] = HalfwaySettings(**dense)
    return METHODS[spec.pop("method", "natural")](**spec)


def settings_arg(text: str) -> dict[str, Any]:
    """An argparse type: JSON of :func:`morph_settings`, checked when the command line is read."""
    try:
        spec = json.loads(text)
        morph_settings(spec)
    except (json.JSONDecodeError, TypeError, ValueError) as err:
        raise argparse.ArgumentTypeError(f"not settings of a morph method: {text!r} ({err})") from None
    return spec


def load_pair(size: int | None = None) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """The bundled astronaut -> cat pair ``(1, 3, H, W)`` x 2 with their points ``(M, 2)`` x 2, resized to ``size``
    x ``size`` (antialiased bilinear; pixel centres stay at integers) when given."""
    from torchfluidwarp.data import load_sample, load_sample_points

    a, b = load_sample("astronaut"), load_sample("cat")
    pa, pb = load_sample_points("astronaut"), load_sample_points("cat")
    if size is None or size == a.shape[-1]:
        return a, b, pa, pb
    s = size / a.shape[-1]
    resize = lambda x: torch.nn.functional.interpolate(
        x, (size, size), mode="bilinear", align_corners=False, antialias=True
    )
    return resize(a), resize(b), (pa + 0.5) * s - 0.5, (pb + 0.5) * s - 0.5


def write_samples(folder: pathlib.Path, size: int, mode: str = "bilinear") -> dict[str, Tensor]:
    """The bundled astronaut and cat resized to ``size x size`` (``mode``, antialiased when bilinear) as
    ``folder/<name>.png``; returns their points, float64, moved along (pixel centres at integers)."""
    from torchfluidwarp.core.grid import rescale_points, scale_factor
    from torchfluidwarp.data import load_sample, load_sample_points
    from torchfluidwarp.io import write_image

    points = {}
    for name in ("astronaut", "cat"):
        image = load_sample(name)
        resized = torch.nn.functional.interpolate(
            image, size=(size, size), mode=mode, align_corners=False, antialias=mode == "bilinear"
        )
        write_image(folder / f"{name}.png", resized[0].clamp(0, 1))
        scale = scale_factor(tuple(image.shape[-2:]), (size, size), dtype=torch.float64)
        points[name] = rescale_points(load_sample_points(name).double(), scale)
    return points
