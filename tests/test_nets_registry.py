"""The one registry of network architectures (spare_twin.nets.registry): every preset resolves through
it, what it declares is what the networks do, and nets code asks it instead of testing names."""

import re
from pathlib import Path

import pytest
import torch

from spare_twin.nets import data, profile_train, registry, sample_sources
from spare_twin.nets.presets import ARCHS, PRESETS

NETS = Path(registry.__file__).parent


def _batch(net, B=2):
    Kv = 1 if net.mode == "tmp" else net.frames
    return {
        "x": torch.rand(B, net.frames, net.height, net.width),
        "K": torch.tensor([[125.0, 0, 63.5], [0, 125.0, 47.5], [0, 0, 1]]).expand(B, Kv, 3, 3),
        "T_world_camera": torch.eye(4).expand(B, Kv, 4, 4),
        "print_scale": torch.full((B,), 0.08),
    }


def test_every_architecture_a_config_accepts_has_one_entry():
    assert tuple(registry.ARCHITECTURES) == ARCHS == tuple(sample_sources.SAMPLE_SOURCES)
    assert all(name == a.name for name, a in registry.ARCHITECTURES.items())


@pytest.mark.parametrize("name", list(PRESETS))
def test_every_preset_resolves_through_the_registry(name):
    """Its network builds, reads what the registry says it reads, and decodes as declared."""
    net = PRESETS[name].net
    arch = registry.architecture(net)
    assert arch is registry.ARCHITECTURES[net.arch]
    assert sample_sources.samples_of(net) in (data.stored_samples, profile_train.profile_samples)
    assert (arch.reads == "posed views") == net.posed
    assert (arch.reads == "profile") == (net.mode == "profile") == arch.observed_samples
    if "tmp" in name:
        return  # 100-frame stacks: building is the check (the forward pass costs seconds on a CPU)
    torch.manual_seed(0)
    model = registry.build_model(net).eval()
    assert type(model) is type(arch.build(net))
    inputs = _batch(net) if arch.reads != "profile" else {"x": torch.rand(2, net.frames, net.height, net.width)}
    res = registry.decode(model, net, inputs, torch.tensor([2, 5]))
    assert ("pred_n" in res) != arch.needs_count  # a network that needs the count does not give one
    assert ("lengths_known" in res) == (net.task != "count")
    if arch.needs_count:
        assert registry.decode(model, net, inputs) == {}  # nothing to say without the count
        with pytest.raises(ValueError, match="n_links"):
            model(**inputs)
    out = model(**inputs, **({"n_links": torch.tensor([2, 5])} if arch.takes_count else {}))
    assert ("angles_sincos" in out) == (arch.reads == "profile" and net.predict_angles)


def test_an_unknown_architecture_is_a_one_line_error():
    from spare_twin.errors import SpareTwinError

    with pytest.raises(SpareTwinError, match="net.arch: 'resnet'"):
        registry.architecture("resnet")
    with pytest.raises(SpareTwinError, match="net.arch: 'resnet'"):
        sample_sources.samples_of("resnet")


def test_nets_code_asks_the_registry_instead_of_testing_architecture_names():
    """Outside the registry and the configuration's own checks (presets.py), no module of nets
    branches on an architecture's name."""
    branch = re.compile(r"\.arch\s*(==|!=|in\b|not in\b)")
    offenders = [
        f"{p.name}:{i}"
        for p in sorted(NETS.glob("*.py"))
        if p.name not in ("registry.py", "presets.py")
        for i, line in enumerate(p.read_text().splitlines(), 1)
        if branch.search(line)
    ]
    assert offenders == []
