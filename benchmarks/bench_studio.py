"""Studio preview latency: 512x512 pair, 20 points, warm (after the first fit), request to frame returned.

Usage: ``python benchmarks/bench_studio.py [PREVIEW_SIZE]`` (default 320). One thread, the studio's JSON API
in-process: one cold preview, then six warm ones after moving one of B's points. Figures: docs/benchmarks.md.
"""

from __future__ import annotations

import statistics
import sys
import time
import warnings

import numpy as np
import torch
from starlette.testclient import TestClient

from torchfluidwarp.apps.studio import StudioConfig, create_app
from torchfluidwarp.data import load_sample, load_sample_points

SETTINGS = {"method": "natural", "steps": 8}  # the studio page's defaults (control applies to "paper")


def main() -> None:
    warnings.simplefilter("ignore")
    torch.set_num_threads(1)  # as `torchfluidwarp studio` does (studio/server.py)
    preview_size = int(sys.argv[1]) if len(sys.argv) > 1 else 320
    print("torch threads", torch.get_num_threads(), "preview_size", preview_size, flush=True)
    images = {"a": (load_sample("astronaut"), "astronaut.png"), "b": (load_sample("cat"), "cat.png")}
    app = create_app(StudioConfig(token="t", allowed_hosts=("testserver",), preview_size=preview_size), images=images)
    client, headers = TestClient(app), {"X-Studio-Token": "t"}
    pa = load_sample_points("astronaut")[:20].tolist()
    pb = load_sample_points("cat")[:20].tolist()

    def once(points_b: list) -> tuple[float, float, dict]:
        c0, t0 = time.process_time(), time.perf_counter()
        body = {"points_a": pa, "points_b": points_b, "settings": SETTINGS}
        r = client.post("/api/morph/preview", json=body, headers=headers)
        meta = r.json()
        if r.status_code != 200:
            raise RuntimeError(meta)
        f = client.get(f"/api/morph/frame?gen={meta['generation']}&k=4&kind=blend", headers=headers)
        if f.status_code != 200:
            raise RuntimeError(f.text)
        return time.perf_counter() - t0, time.process_time() - c0, meta

    wall, cpu, meta = once(pb)
    print(f"cold: {wall:.2f} s (cpu {cpu:.2f} s), mean error {meta['mean_error']:.2f} px", flush=True)
    rng = np.random.default_rng(0)
    latencies = []
    for i in range(6):
        pb = [list(p) for p in pb]
        k = i % 20
        pb[k] = [pb[k][0] + float(rng.uniform(-4, 4)), pb[k][1] + float(rng.uniform(-4, 4))]
        wall, cpu, meta = once(pb)
        latencies.append(wall)
        split = ", ".join(f"{k} {v:.2f}" for k, v in meta["seconds"].items())
        print(
            f"warm {i}: {wall:.2f} s (cpu {cpu:.2f} s), mean error {meta['mean_error']:.2f} px; morph s: {split}",
            flush=True,
        )
    print(
        f"warm latency median {statistics.median(latencies):.2f} s, min {min(latencies):.2f}, max {max(latencies):.2f}"
    )


if __name__ == "__main__":
    main()
