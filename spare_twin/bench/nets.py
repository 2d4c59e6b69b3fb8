"""Inference benchmark: samples/s and latency per sample on the CPU (or a GPU)."""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from spare_twin.dataset.synthetic import SyntheticSpec, make_sample
from spare_twin.errors import SpareTwinError
from spare_twin.nets import checkpoint as ckpt
from spare_twin.nets.models import model_inputs
from spare_twin.nets.presets import NetConfig, get_preset
from spare_twin.nets.registry import architecture, build_model
from spare_twin.validate import check_whole

DEVICES = ("cpu", "cuda")


def example_batch(net: NetConfig, batch_size: int, seed: int = 0) -> dict:
    """A realistic batch (synthetic renders of sampled chains) so the voxel front end sees real sparsity."""
    spec = SyntheticSpec(mode=net.mode, input=net.input, frames=net.frames, seed=seed)
    s = make_sample(spec, "bench", 0)
    return {k: torch.as_tensor(np.repeat(np.asarray(v)[None], batch_size, 0)) for k, v in s.items()}


@torch.no_grad()
def bench_inference(
    model,
    net: NetConfig,
    batch_sizes: Sequence[int] = (1, 16),
    warmup: int = 2,
    iters: int = 10,
    threads: int | None = None,
    device: str = "cpu",
) -> dict:
    """{threads, device, batch_sizes: {batch_size: {samples_per_s, latency_ms_per_sample,
    batch_latency_ms}}} (median over iters)."""
    if not batch_sizes:
        raise SpareTwinError("batch_sizes: none given")
    for bs in batch_sizes:
        check_whole("batch_sizes", bs, 1)
    check_whole("warmup", warmup, 0)
    check_whole("iters", iters, 1)
    if threads is not None:
        check_whole("threads", threads, 0)  # 0: torch's default, as in TrainConfig
    if device not in DEVICES:
        raise SpareTwinError(f"device {device!r}: choose {' or '.join(DEVICES)}")
    if device == "cuda" and not torch.cuda.is_available():
        raise SpareTwinError("device cuda: no CUDA device here")
    if threads:
        torch.set_num_threads(threads)
    model = model.to(device).eval()
    out = {}
    for bs in batch_sizes:
        inputs = model_inputs(example_batch(net, bs), device)
        kw = {"n_links": torch.full((bs,), 3, device=device)} if architecture(net).needs_count else {}
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


@dataclass(frozen=True)
class NetBench:
    """`bench_network`'s figures for one network."""

    model: str
    """The checkpoint file, or the preset name of an untrained network."""
    parameters: int
    threads: int
    device: str
    batch_sizes: dict
    """{batch size: {samples_per_s, latency_ms_per_sample, batch_latency_ms}}."""

    def to_json(self) -> dict:
        return {
            "threads": self.threads,
            "device": self.device,
            "batch_sizes": self.batch_sizes,
            "model": self.model,
            "parameters": self.parameters,
        }


def bench_network(
    model_path: str | Path | None = None,
    preset: str | None = None,
    batch_sizes: Sequence[int] = (1, 16),
    iters: int = 10,
    threads: int | None = None,
    device: str = "cpu",
) -> NetBench:
    """Inference speed of a checkpoint, or of an untrained network of `preset` (speed does not depend
    on the weights); neither: the shipped predict model."""
    if model_path is not None and preset is not None:
        raise SpareTwinError("model_path, preset: give at most one")
    if preset is not None:
        net = get_preset(preset).net
        model, name = build_model(net), preset
    else:
        path = model_path or ckpt.default_model("predict")
        model, net, _ = ckpt.load_model(path)
        name = str(path)
    res = bench_inference(model, net, batch_sizes, iters=iters, threads=threads, device=device)
    parameters = int(sum(p.numel() for p in model.parameters()))
    return NetBench(name, parameters, res["threads"], res["device"], res["batch_sizes"])
