"""Benchmark: the paper's keyframe fit, torchfluidwarp against PhiFlow 3.4 (torch backend), timed in one run.

The set-up of ``bench_keyframes.py`` (``_common.flow_instance(--seed)``, 64x64 closed box, 10 steps, control 5x5,
float64, L-BFGS from zero forces until every point is within ``--tolerance`` px), fitted by ``fit_keyframes(...,
method="lbfgs")``, by this script's copy of its L-BFGS loop around torchfluidwarp, and by the same loop around the
same scheme written in PhiFlow (midpoint advection, ``make_incompressible``, ``advect.points``). Also: the gradients
at zero forces compared, PhiFlow's pressure solver as ``math.SolveTape`` records it, each fitted control replayed
in the other library. Needs ``pip install "phiflow>=3.4,<3.5"``. Set-up and figures: docs/benchmarks.md,
"Keyframe fit against PhiFlow 3.4".
"""

from __future__ import annotations

import math
import re
import statistics
import sys
import time
import warnings
from collections import Counter
from collections.abc import Callable
from dataclasses import asdict, dataclass
from typing import Any

import torch
import torch.nn.functional as F
from _common import FRAME, Instance, finish, flow_instance, log, parser, pyplot, rows_table, save_figure, start
from bench_keyframes import PAPER_SECONDS
from torch import Tensor

from torchfluidwarp.control import fit_keyframes
from torchfluidwarp.warp import FluidWarp

CONTROL = (5, 5)
DT = 1.0


@dataclass
class FitRun:
    """One fit (one repeat) of one library."""

    library: str
    seconds: float
    cpu_seconds: float
    evaluations: int
    mean_error: float
    max_error: float
    reached: bool
    stopped: str  # "targets reached", "L-BFGS stopped", "max_iter", "time cap", "non-finite loss"
    final_loss: float

    @property
    def ms_per_evaluation(self) -> float:
        return 1e3 * self.seconds / max(self.evaluations, 1)


class _Stop(Exception):
    pass


def lbfgs_fit(
    library: str,
    params: list[Tensor],
    endpoints: Callable[[], Tensor],
    target: Tensor,
    tolerance: float,
    max_iter: int,
    time_cap_s: float,
    errors: tuple[type[Exception], ...] = (),
) -> FitRun:
    """``fit_keyframes``'s L-BFGS loop around any simulator: ``endpoints()`` gives the ``(M, 2)`` end points, px.

    The optimiser settings, the stopping rule (every point within ``tolerance``, checked when the loss improves)
    and the restore of the best iterate are those of :func:`torchfluidwarp.control.keyframes.fit_keyframes`; the clock
    starts after the optimiser is built and stops after the final forward, as ``KeyframeFit.seconds`` does.
    ``errors`` raised by the simulator stop the fit instead of the run.
    """
    settings = dict(lr=1.0, max_iter=max_iter, max_eval=max_iter * 2, history_size=20, tolerance_grad=1e-12)
    optimizer = torch.optim.LBFGS(params, **settings, tolerance_change=1e-14, line_search_fn="strong_wolfe")
    history: list[float] = []
    best_loss, best_state = math.inf, None
    start, cpu0 = time.perf_counter(), time.process_time()

    def closure() -> Tensor:
        nonlocal best_loss, best_state
        optimizer.zero_grad()
        end = endpoints()
        loss = 0.5 * ((end - target) ** 2).sum()
        value = float(loss.detach())
        if not math.isfinite(value):
            raise _Stop("non-finite loss")
        loss.backward()
        history.append(value)
        if value < best_loss:
            best_loss, best_state = value, [p.detach().clone() for p in params]
            if float((end.detach() - target).norm(dim=-1).max()) <= tolerance:
                raise _Stop("targets reached")
        if time.perf_counter() - start > time_cap_s:
            raise _Stop("time cap")
        return loss

    try:
        optimizer.step(closure)
        n_iter = optimizer.state[optimizer._params[0]].get("n_iter", 0)  # type: ignore[attr-defined]
        stopped = "L-BFGS stopped" if n_iter < max_iter else "max_iter"
    except _Stop as stop:
        stopped = str(stop)
    except errors as exc:  # the simulator gave up (e.g. a failed linear solve): keep the best iterate
        stopped = f"{type(exc).__name__} raised"
    if best_state is not None:
        with torch.no_grad():
            for p, v in zip(params, best_state):
                p.copy_(v)
    with torch.no_grad():
        err = (endpoints() - target).norm(dim=-1)
    return FitRun(library, time.perf_counter() - start, time.process_time() - cpu0, len(history), float(err.mean()),
                  float(err.max()), bool(err.max() <= tolerance), stopped, best_loss)  # fmt: skip


def upsample(control: Tensor, grid: tuple[int, int]) -> Tensor:
    """Control ``(T, 2, K_y, K_x)`` -> forces ``(T, 2, h, w)`` at the cell centres, as ``ControlGrid`` does it."""
    return F.interpolate(control, size=grid, mode="bicubic", align_corners=True)


class TorchfluidwarpSim:
    """torchfluidwarp's forward map: control ``(T, 2, K_y, K_x)`` -> end points ``(M, 2)`` px."""

    def __init__(self, source: Tensor, grid: tuple[int, int], steps: int) -> None:
        self.source, self.grid = source, grid
        self.warp = FluidWarp(grid, steps, DT, image_size=FRAME).to(source.dtype)

    def endpoints(self, control: Tensor) -> Tensor:
        return self.warp.carry_points(self.source[None], upsample(control, self.grid)[None])[0, -1]

    def pressure_iterations(self, control: Tensor) -> list[int]:
        with torch.no_grad():
            out = self.warp.rollout(upsample(control, self.grid)[None])
        return [p for _, p in out.iterations]


class PhiFlowSim:
    """The same fluid written with PhiFlow 3.4's torch backend (see the module doc)."""

    def __init__(self, source: Tensor, grid: tuple[int, int], steps: int, method: str, tolerance: float) -> None:
        import phi.torch.flow as pf  # the torch backend becomes PhiFlow's default
        from phi.field import sample

        self.pf, self.steps, self.grid = pf, steps, grid
        # None: make_incompressible's own default Solve(); tolerance 0: that Solve's own tolerance
        self.solve = (
            None
            if method == "auto" and tolerance == 0
            else pf.Solve(method, rel_tol=tolerance or None, abs_tol=tolerance or None)
        )
        h, w = grid
        H, W = FRAME
        self.scale = torch.tensor([w / W, h / H], dtype=source.dtype)
        # PhiFlow's box is [0, w] x [0, h] with cell centres at i + 0.5: a pixel centre x goes to (x + 0.5) w / W
        self.source = pf.tensor((source + 0.5) * self.scale, pf.instance("points"), pf.channel(vector="x,y"))
        self.bounds = pf.Box(x=w, y=h)

        def midpoint(data: Any, velocity: Any, dt: float, v0: Any = None) -> Any:
            # RK2 (explicit midpoint), in the form of PhiFlow's own integrators (phi.physics.advect.rk4)
            if v0 is None:
                v0 = sample(velocity, data.geometry, at=data.sampled_at, boundary=data.boundary)
            v_half = sample(velocity, data.points + 0.5 * dt * v0, at=data.sampled_at, boundary=data.boundary)
            return data.points + dt * v_half

        self.integrator = midpoint

    def incompressible(self, v: Any) -> Any:
        if self.solve is None:
            return self.pf.fluid.make_incompressible(v)[0]  # as a user would call it
        return self.pf.fluid.make_incompressible(v, (), self.solve)[0]

    def endpoints(self, control: Tensor) -> Tensor:
        pf = self.pf
        h, w = self.grid
        fine = upsample(control, self.grid)  # (T, 2, h, w)
        v = pf.StaggeredGrid(0, pf.extrapolation.ZERO, self.bounds, x=w, y=h)
        pts = self.source
        for t in range(self.steps):
            values = pf.tensor(fine[t].permute(2, 1, 0), pf.spatial("x,y"), pf.channel(vector="x,y"))
            force = pf.CenteredGrid(values, pf.extrapolation.ZERO, self.bounds, x=w, y=h)
            v = v + DT * pf.resample(force, to=v)
            v = pf.advect.semi_lagrangian(v, v, DT, integrator=self.integrator)
            v = self.incompressible(v)
            pts = pf.advect.points(pts, v, DT, integrator=self.integrator)
        return pts.native("points,vector") / self.scale - 0.5

    def solver_report(self, control: Tensor) -> dict[str, Any]:
        """Which pressure solver PhiFlow runs, recorded by ``math.SolveTape``.

        First a forward with ``make_incompressible``'s own default ``Solve()`` (it may raise PhiFlow's
        ``ConvergenceException``: its message is recorded), then an objective and gradient with the fit's solve.
        """
        pf = self.pf
        saved, self.solve = self.solve, None
        with warnings.catch_warnings(), pf.math.SolveTape() as tape:
            warnings.simplefilter("ignore")
            try:
                self.endpoints(control.detach())
                default_outcome = "no error"
            except pf.math.ConvergenceException as exc:
                default_outcome = f"{type(exc).__name__}: {exc}"
            finally:
                self.solve = saved
        default_run = {"outcome": default_outcome, "solves_run": len(tape), **self._describe(list(tape))}
        c = control.detach().clone().requires_grad_()
        with warnings.catch_warnings(record=True) as caught, pf.math.SolveTape() as tape:
            warnings.simplefilter("always")
            end = self.endpoints(c)
            n_forward = len(tape)
            end.pow(2).sum().backward()
        infos = list(tape)
        msgs = Counter(f"{w.category.__name__}: {str(w.message).splitlines()[0][:160]}" for w in caught)
        default_solve = pf.fluid.make_incompressible.__defaults__
        return {
            "make_incompressible_default_solve": repr(next(d for d in default_solve if isinstance(d, pf.Solve))),
            "default_solve_run": default_run,
            "fit_solve": "make_incompressible's default" if self.solve is None else repr(self.solve),
            "forward": self._describe(infos[:n_forward]),
            "gradient": self._describe(infos[n_forward:]),
            "warnings": dict(msgs),
        }

    @staticmethod
    def _describe(infos: list[Any]) -> dict[str, Any]:
        """Summary of ``SolveInfo`` records."""
        residuals = [float(m) for i in infos for m in re.findall(r"norm\(residual\)=([0-9.eE+-]+)", str(i.msg))]
        return {
            "solves": len(infos),
            "requested": sorted({repr(i.solve) for i in infos}),
            "method_setting": sorted({i.solve.method for i in infos}),
            "implementation": sorted({str(i.method) for i in infos}),
            "rank_deficiency": sorted({str(i.solve.rank_deficiency) for i in infos}),
            "iterations": sorted({int(i.iterations.max) for i in infos}),
            "converged": all(bool(i.converged.all) for i in infos),
            "max_residual_norm": max(residuals) if residuals else math.nan,
            "median_solve_ms": 1e3 * statistics.median(float(i.solve_time) for i in infos) if infos else math.nan,
        }


def gradient_at(endpoints: Callable[[Tensor], Tensor], control: Tensor, target: Tensor) -> tuple[Tensor, float]:
    """The objective's gradient at ``control`` and the wall time of that evaluation."""
    c = control.detach().clone().requires_grad_()
    t0 = time.perf_counter()
    (0.5 * ((endpoints(c) - target) ** 2).sum()).backward()
    return c.grad, time.perf_counter() - t0


def summary(runs: list[FitRun], label: str) -> dict[str, Any]:
    med = lambda key: statistics.median(getattr(r, key) for r in runs)  # noqa: E731
    return dict(
        label=label, repeats=len(runs), seconds=med("seconds"), cpu_seconds=med("cpu_seconds"),
        evaluations=med("evaluations"), ms_per_evaluation=med("ms_per_evaluation"), mean_error=med("mean_error"),
        max_error=med("max_error"), reached=f"{sum(r.reached for r in runs)}/{len(runs)}",
        stopped="; ".join(sorted(Counter(r.stopped for r in runs))),
        same_each_repeat=len({(r.evaluations, round(r.mean_error, 10)) for r in runs}) == 1,
    )  # fmt: skip


def plot(path: str, rows: dict[str, dict[str, Any]], names: dict[str, str], title: str) -> None:
    """Bar chart of fit wall time (log axis): the paper's quoted 5 minutes, PhiFlow and torchfluidwarp."""
    labels = ["paper\n(5 min, quoted,\nnot measured)"] + list(names.values())
    secs = [PAPER_SECONDS] + [rows[k]["seconds"] for k in names]
    notes = ["300 s"] + [
        f"{r['seconds']:.1f} s: {r['evaluations']:g} evals x {r['ms_per_evaluation']:.0f} ms,\n"
        f"mean err {r['mean_error']:.3f} px, max {r['max_error']:.3f} px"
        + ("" if r["reached"].startswith(str(r["repeats"])) else f" (not reached: {r['stopped']})")
        for r in (rows[k] for k in names)
    ]
    fig, ax = pyplot().subplots(figsize=(8.0, 0.9 * len(labels) + 1.3), dpi=120)
    bars = ax.barh(range(len(labels)), secs, color=["#9e9e9e", "#d95f02", "#1b9e77"][: len(labels)])
    for bar, note in zip(bars, notes):
        ax.text(bar.get_width() * 1.1, bar.get_y() + bar.get_height() / 2, note, va="center", fontsize=8)
    ax.set_xscale("log")
    ax.set_xlim(min(secs) / 2, max(secs) * 30)
    ax.set_yticks(range(len(labels)), labels, fontsize=8)
    ax.invert_yaxis()
    ax.set_xlabel("wall time of the keyframe fit, s (log scale)")
    ax.set_title(title, fontsize=9)
    fig.tight_layout()
    save_figure(fig, path)


def solver_lines(solver: dict[str, Any], steps: int, ours_iters: list[int]) -> list[str]:
    """What :meth:`PhiFlowSim.solver_report` found, and torchfluidwarp's pressure solve."""
    fw, gr, dflt = solver["forward"], solver["gradient"], solver["default_solve_run"]
    return [
        "\nPressure solve in the closed box (control 0.01 everywhere; SolveTape records every solve)",
        f"  PhiFlow make_incompressible's default solve argument: Solve({solver['make_incompressible_default_solve']})",
        f"  with it, a forward: {dflt['solves_run']} of {steps} solves ran, method {dflt['method_setting']}, "
        f"implementation {dflt['implementation']}, residual norms up to {dflt['max_residual_norm']:.3g}; "
        f"outcome: {dflt['outcome']}",
        f"  the fit's solve: {solver['fit_solve']}",
        f"  PhiFlow, forward: {fw['solves']} solves, Solve {fw['requested']}, i.e. method {fw['method_setting']}, "
        f"ran {fw['implementation']}, rank_deficiency {fw['rank_deficiency']}, iterations {fw['iterations']}, "
        f"converged {fw['converged']}, residual norms up to {fw['max_residual_norm']:.3g}, median "
        f"{fw['median_solve_ms']:.1f} ms per solve",
        f"  PhiFlow, gradient: {gr['solves']} solves, method {gr['method_setting']}, ran {gr['implementation']}, "
        f"converged {gr['converged']}",
        *(f"  PhiFlow warning (x{n}): {msg}" for msg, n in solver["warnings"].items()),
        "  torchfluidwarp: pressure by its exact DCT Neumann solve (its CG's preconditioner), implicit adjoint; "
        f"iterations per step {sorted(set(ours_iters))}",
    ]


def main(argv: list[str] | None = None) -> int:
    p = parser(__doc__, quick="32x32 fluid, 5 steps, 6 points, short caps")
    p.add_argument("--plot", metavar="PATH.png", help="also write a bar chart of the fit times to PATH.png")
    p.add_argument("--seed", type=int, default=0, help="the flow instance (default 0)")
    p.add_argument("--repeats", type=int, help="torchfluidwarp fits (default 3; --quick 1)")
    p.add_argument("--phiflow-repeats", type=int, default=1, help="PhiFlow fits (default 1)")
    p.add_argument("--tolerance", type=float, default=0.05, help="px: stop once every point is within it")
    p.add_argument("--max-iter", type=int, help="L-BFGS iterations at most (default 200; --quick 50)")
    p.add_argument("--time-cap-s", type=float, help="wall-time cap of one fit (default 600; --quick 60)")
    p.add_argument("--phiflow-solve", default="auto",
                   help="method of PhiFlow's pressure Solve (default 'auto', make_incompressible's)")  # fmt: skip
    p.add_argument("--phiflow-tol", type=float, default=1e-9,
                   help="rel_tol and abs_tol of PhiFlow's pressure Solve (default 1e-9; 0: PhiFlow's own, 1e-12 in "
                   "float64, with which its direct solve fails its own residual check on these flows)")  # fmt: skip
    args = p.parse_args(argv)
    repeats = args.repeats or (1 if args.quick else 3)
    max_iter = args.max_iter or (50 if args.quick else 200)
    cap = args.time_cap_s or (60.0 if args.quick else 600.0)
    if min(args.threads, repeats, args.phiflow_repeats, max_iter) < 1 or not (args.tolerance > 0 and cap > 0):
        p.error("--threads, --repeats, --phiflow-repeats, --max-iter must be >= 1; --tolerance, --time-cap-s > 0")
    try:
        import phi

        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            import phi.torch.flow  # noqa: F401
    except ImportError as exc:
        print(f'bench_phiflow: PhiFlow is needed: pip install "phiflow>=3.4,<3.5" ({exc})', file=sys.stderr)
        return 2
    grid, steps, points = ((32, 32), 5, 6) if args.quick else ((64, 64), 10, 14)
    dtype = torch.float64
    phi.math.set_global_precision(64)
    info = start("bench_phiflow", args.threads, f", PhiFlow {phi.__version__}" + (" [--quick]" if args.quick else ""))
    n_params = 2 * steps * CONTROL[0] * CONTROL[1]
    print(f"set-up: {grid[0]}x{grid[1]} fluid in a closed box, {FRAME[1]}x{FRAME[0]} px frame, {steps} steps, "
          f"dt {DT:g}, {points} points, control {CONTROL[0]}x{CONTROL[1]} ({n_params} parameters), float64, "
          f"tolerance {args.tolerance:g} px (every point), max_iter {max_iter}, time cap {cap:g} s a fit")  # fmt: skip
    log("  instance ...")
    inst: Instance = flow_instance(args.seed, points, grid, steps)
    src, tgt = inst.tensors(dtype)
    d = inst.describe()
    print(f"instance: {inst.name}, {len(inst.source)} points, displacement {d['min_disp']:.2f} to "
          f"{d['max_disp']:.2f} px, min spacing {d['min_spacing']:.2f} px, targets at least {d['min_wall']:.2f} px "
          "from the walls")  # fmt: skip
    ours = TorchfluidwarpSim(src, grid, steps)
    theirs = PhiFlowSim(src, grid, steps, args.phiflow_solve, args.phiflow_tol)
    zero = torch.zeros(steps, 2, *CONTROL, dtype=dtype)
    fit_args = dict(image_size=FRAME, grid=grid, steps=steps, control=CONTROL, max_iter=max_iter, dtype=dtype,
                    tolerance=args.tolerance, progress=False, method="lbfgs")  # fmt: skip

    log("  warm-up ...")  # one-time costs kept out of the fits: kernels, caches, the first LBFGS constructor
    fit_keyframes(src[:1], src[:1] + 1.0, **{**fit_args, "grid": 8, "steps": 2, "control": (3, 3), "max_iter": 3})
    for _ in range(2):
        g_ours, t_ours = gradient_at(ours.endpoints, zero, tgt)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        g_phi, t_phi_first = gradient_at(theirs.endpoints, zero, tgt)
        g_phi, t_phi = gradient_at(theirs.endpoints, zero, tgt)
    cosine = float(F.cosine_similarity(g_ours.flatten(), g_phi.flatten(), dim=0))
    norm_ratio = float(g_phi.norm() / g_ours.norm())
    print(f"\nGradient at zero forces (objective + gradient, one evaluation): torchfluidwarp {1e3 * t_ours:.0f} ms, "
          f"PhiFlow {1e3 * t_phi:.0f} ms (its first call {1e3 * t_phi_first:.0f} ms); cosine between the two "
          f"gradients {cosine:.6f}, |g PhiFlow| / |g torchfluidwarp| {norm_ratio:.6f}")  # fmt: skip
    log("  PhiFlow's solver, recorded with math.SolveTape ...")
    solver = theirs.solver_report(zero + 0.01)
    ours_iters = ours.pressure_iterations(zero + 0.01)
    print("\n".join(solver_lines(solver, steps, ours_iters)), flush=True)

    impl = "/".join(solver["forward"]["implementation"])
    labels = {
        "fit_keyframes": "torchfluidwarp `fit_keyframes`",
        "ours_loop": "torchfluidwarp, this script's copy of the loop",
        "phiflow": f"PhiFlow {phi.__version__} (torch backend, eager, pressure: {impl})",
    }
    runs: dict[str, list[FitRun]] = {k: [] for k in labels}
    fitted: dict[str, Tensor] = {}
    for rep in range(max(repeats, args.phiflow_repeats)):
        if rep < repeats:
            log(f"  torchfluidwarp fit_keyframes, repeat {rep + 1}/{repeats} ...")
            cpu0 = time.process_time()
            fit = fit_keyframes(src, tgt, **fit_args)
            err = fit.error[0]
            stopped = "targets reached" if fit.reached else ("L-BFGS stopped" if fit.converged else "max_iter")
            runs["fit_keyframes"].append(FitRun(
                "torchfluidwarp", fit.seconds, time.process_time() - cpu0, fit.evaluations, float(err.mean()),
                float(err.max()), fit.reached, stopped, min(fit.loss_history, default=math.nan),
            ))  # fmt: skip
            fitted["ours"] = fit.forces.weight.detach()[0]
            log(f"  torchfluidwarp, the script's loop, repeat {rep + 1}/{repeats} ...")
            c = zero.clone().requires_grad_()
            runs["ours_loop"].append(
                lbfgs_fit("torchfluidwarp", [c], lambda: ours.endpoints(c), tgt, args.tolerance, max_iter, cap)
            )
        if rep < args.phiflow_repeats:
            log(f"  PhiFlow, repeat {rep + 1}/{args.phiflow_repeats} (about 1 minute per 10 evaluations) ...")
            c = zero.clone().requires_grad_()
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                stop = (theirs.pf.math.ConvergenceException,)
                fit_run = lbfgs_fit(
                    "phiflow", [c], lambda: theirs.endpoints(c), tgt, args.tolerance, max_iter, cap, stop
                )
                runs["phiflow"].append(fit_run)
            fitted["phiflow"] = c.detach()

    rows = {k: summary(v, labels[k]) for k, v in runs.items()}
    base = rows["fit_keyframes"]
    paper = dict(label="paper (as quoted in the issue, not measured)", repeats="-", seconds=PAPER_SECONDS)
    table_rows = [{**paper, "cpu": "-", "evals": "-", "ms": "-", "mean": "-", "max": "-", "reached": "-",
                   "stopped": "-", "ratio": f"{PAPER_SECONDS / base['seconds']:.0f}x"}]  # fmt: skip
    table_rows += [{**r, "cpu": f"{r['cpu_seconds']:.2f}", "evals": f"{r['evaluations']:g}",
                    "ms": f"{r['ms_per_evaluation']:.1f}", "mean": f"{r['mean_error']:.4f}",
                    "max": f"{r['max_error']:.4f}", "ratio": f"{r['seconds'] / base['seconds']:.1f}x"}
                   for r in rows.values()]  # fmt: skip
    print(f"\nKeyframe fit, {inst.name}: wall time of the fit (median over repeats), CPU time of this process, "
          "evaluations (objective + gradient), final errors (px)\n")  # fmt: skip
    spec = "fit {label} | repeats {repeats} | fit s (median) {seconds:.2f} | CPU s {cpu} | evals {evals} | ms/eval "
    spec += "{ms} | mean err px {mean} | max err px {max} | reached {reached} | stopped by {stopped} | time / "
    print(rows_table(table_rows, spec + "torchfluidwarp {ratio}", markdown=True))
    ratio = {k: rows["phiflow"][k] / base[k] for k in ("seconds", "cpu_seconds", "ms_per_evaluation", "evaluations")}
    print(
        f"\nPhiFlow / torchfluidwarp: fit time {ratio['seconds']:.1f}x, CPU time {ratio['cpu_seconds']:.1f}x, "
        f"time per evaluation {ratio['ms_per_evaluation']:.1f}x, evaluations {ratio['evaluations']:.2f}x"
    )
    print(f"paper (5 min, quoted) / torchfluidwarp: {PAPER_SECONDS / base['seconds']:.0f}x; "
          f"paper / PhiFlow: {PAPER_SECONDS / rows['phiflow']['seconds']:.1f}x")  # fmt: skip

    # each fitted control replayed in the other library: how far apart the two discretisations are
    cross = []
    with torch.no_grad(), warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for name, u in fitted.items():
            a, b = ours.endpoints(u), theirs.endpoints(u)
            gap = (a - b).norm(dim=-1)
            cross.append(dict(by=name, ours=float((a - tgt).norm(dim=-1).mean()), gap_max=float(gap.max()),
                              phiflow=float((b - tgt).norm(dim=-1).mean()), gap_mean=float(gap.mean())))  # fmt: skip
    print("\nEach fitted control replayed in both libraries (mean error to the targets, px; end-point gap, px)")
    spec = "control fitted by {by} | torchfluidwarp mean err {ours:.4f} | PhiFlow mean err {phiflow:.4f} | "
    print(rows_table(cross, spec + "gap mean {gap_mean:.4f} | gap max {gap_max:.4f}"))
    if args.plot:
        title = f"Keyframe fit ({inst.name}): {grid[0]}x{grid[1]} fluid, {steps} steps, {n_params} parameters, "
        title += f"{points} points, float64\n1 torch thread, {info['cpu']}, {info['date'][:16].replace('T', ' ')}"
        short = impl.replace("scipy.sparse.linalg.", "scipy ")
        names = {"phiflow": f"PhiFlow {phi.__version__}\n(torch backend, eager,\npressure: {short})"}
        names["fit_keyframes"] = "torchfluidwarp\nfit_keyframes"
        plot(args.plot, rows, names, title)
        print(f"plot written to {args.plot}")
    gradient = dict(cosine=cosine, norm_ratio=norm_ratio, torchfluidwarp_s=t_ours, phiflow_s=t_phi,
                    phiflow_first_s=t_phi_first)  # fmt: skip
    info["phiflow"] = phi.__version__
    finish(info, {"args": vars(args), "instance": asdict(inst), "gradient_at_zero": gradient,
                  "solver": {"phiflow": solver, "torchfluidwarp_pressure_iterations": ours_iters},
                  "runs": {k: [asdict(r) for r in v] for k, v in runs.items()}, "summary": rows,
                  "ratio_phiflow_over_torchfluidwarp": ratio, "cross": cross, "paper_seconds_quoted": PAPER_SECONDS},
           args.json)  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
