"""Inference benchmark: samples/s and latency per sample on the CPU (or a GPU)."""

from __future__ import annotations

import time

import numpy as np
import torch

from spare_twin.nets.models import model_inputs
from spare_twin.nets.presets import NetConfig


def example_batch(net: NetConfig, batch_size: int, seed: int = 0) -> dict:
    """A realistic batch (synthetic renders of sampled chains) so the voxel front end sees real sparsity."""
    from spare_twin.dataset.synthetic import SyntheticSpec, make_sample

    spec = SyntheticSpec(mode=net.mode, input=net.input, frames=net.frames, seed=seed)
    s = make_sample(spec, "bench", 0)
    return {k: torch.as_tensor(np.repeat(np.asarray(v)[None], batch_size, 0)) for k, v in s.items()}


@torch.no_grad()
def bench_inference(
    model,
    net: NetConfig,
    batch_sizes=(1, 16),
    warmup: int = 2,
    iters: int = 10,
    threads: int | None = None,
    device: str = "cpu",
) -> dict:
    """{batch_size: {samples_per_s, latency_ms_per_sample, batch_latency_ms}} (median over iters)."""
    if threads:
        torch.set_num_threads(threads)
    model = model.to(device).eval()
    out = {}
    for bs in batch_sizes:
        inputs = model_inputs(example_batch(net, bs), device)
        kw = {"n_links": torch.full((bs,), 3, device=device)} if net.arch in ("conv3d_per_n",) else {}
        times = []
        for i in range(warmup + iters):
            if device != "cpu":
                torch.cuda.synchronize()
            t = time.perf_counter()
            model(**inputs, **kw)
            if device != "cpu":
                torch.cuda.synchronize()
            if i >= warmup:
                times.append(time.perf_counter() - t)
        med = float(np.median(times))
        out[str(bs)] = {
            "samples_per_s": bs / med,
            "latency_ms_per_sample": 1000 * med / bs,
            "batch_latency_ms": 1000 * med,
        }
    return {"threads": torch.get_num_threads(), "device": device, "batch_sizes": out}
