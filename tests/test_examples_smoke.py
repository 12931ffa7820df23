"""Short runs of the examples that train or fit, to keep them working (the docs build runs them in full)."""

import runpy
from pathlib import Path

import matplotlib.pyplot as plt  # the examples draw figures; matplotlib is in the [test] extra
import pytest
import torch

EXAMPLES = Path(__file__).resolve().parent.parent / "examples"


@pytest.fixture(autouse=True)
def _one_thread_and_no_windows(monkeypatch):
    plt.switch_backend("agg")
    n = torch.get_num_threads()
    torch.set_num_threads(1)  # multi-threaded kernels stall on small shared machines
    with torch.random.fork_rng():  # the examples seed torch's global RNG
        yield
    torch.set_num_threads(n)
    plt.close("all")


def test_training_through_the_warp_lowers_the_loss(monkeypatch):
    monkeypatch.setenv("TORCHFLUIDWARP_EXAMPLE_ITERATIONS", "30")
    out = runpy.run_path(str(EXAMPLES / "plot_train_through_warp.py"), run_name="__main__")
    losses = out["losses"]
    assert len(losses) == 30
    assert sum(losses[-5:]) < 0.7 * sum(losses[:5])
    assert out["test_loss"] < 0.7 * out["start_loss"]
