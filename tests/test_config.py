import json

import numpy as np
import pytest

from spare_twin.config import LABEL_SLOTS, ChainSpec, PartDims, sample_chain
from spare_twin.errors import SpareTwinError


def test_sampled_lengths_follow_the_paper_distribution():
    base, links, totals, scaled = [], [], [], 0
    for seed in range(600):
        spec = sample_chain(n_links=1 + seed % 6, seed=seed)
        L = np.array(spec.link_lengths_pu)
        total = L.sum()
        totals.append(total)
        if np.isclose(total, 3.0):
            scaled += 1
            assert L[0] <= 2.0 and (L[1:] <= 1.0).all()
        else:
            assert total < 3.0
            base.append(L[0])
            links.extend(L[1:])
    assert max(totals) <= 3.0 + 1e-12
    # Unscaled draws cover the paper's ranges: base U[1.3, 2.0], links U[0.3, 1.0].
    assert 1.3 <= min(base) < 1.35 and 1.95 < max(base) <= 2.0
    assert 0.3 <= min(links) < 0.35 and 0.95 < max(links) <= 1.0
    # With up to 6 links the sum often exceeds 3 and is normalised to exactly 3.
    assert 150 < scaled < 500


def test_sampling_without_n_is_balanced_over_counts():
    counts = np.bincount([sample_chain(None, seed=s).n_links for s in range(1200)], minlength=7)[1:]
    assert counts.min() > 150 and counts.max() < 250


def test_sampling_is_reproducible_and_seed_dependent():
    assert sample_chain(4, seed=7) == sample_chain(4, seed=7)
    assert sample_chain(4, seed=7).link_lengths_pu != sample_chain(4, seed=8).link_lengths_pu


def test_json_round_trip_is_exact(tmp_path):
    spec = sample_chain(5, seed=3, parts=PartDims(pin_clearance_mm=0.25))
    path = tmp_path / "spec.json"
    path.write_text(spec.to_json())
    again = ChainSpec.from_json_file(path)
    assert again == spec
    assert again.to_json() == spec.to_json()


def test_label_has_seven_slots():
    spec = sample_chain(2, seed=0)
    label = spec.label_lengths()
    assert label.shape == (LABEL_SLOTS,) and (label[3:] == 0).all() and np.allclose(label[:3], spec.link_lengths_pu)


@pytest.mark.parametrize(
    "change, message",
    [
        (dict(n_links=0, link_lengths_pu=[1.5], colors=["red"]), "n_links: 0 is out of range"),
        (dict(n_links=7), "n_links: 7 is out of range"),
        (dict(link_lengths_pu=[1.5, 0.0]), "link 1 length 0.0 must be positive"),
        (dict(link_lengths_pu=[1.5, -0.4]), "must be positive"),
        (dict(colors=["red", "pink"]), "unknown colour 'pink'"),
        (dict(parts={"pin_clearance_mm": 0.02}), "cannot print as a turning joint"),
        (dict(parts={"pin_clearance_mm": 2.5}), "cannot print as a turning joint"),
        (dict(print_scale=0.3), "does not fit"),
        (dict(printer={"bed_x_mm": 90, "bed_y_mm": 90}), "does not fit"),
        (dict(parts={"link_width_mm": 7.5}), "minimum wall"),
        (dict(link_lengths_pu=[1.5, 0.5], colors=["red"]), "colors: needs n_links + 1 = 2"),
        (dict(printer={"bed_x_mm": -200}), "printer.bed_x_mm: -200.0 must be positive"),
        (dict(seed=-3), "seed: -3 must be a non-negative integer"),
    ],
)
def test_bad_configurations_are_rejected_with_one_line(change, message):
    d = dict(n_links=1, link_lengths_pu=[1.5, 0.5], colors=["red", "blue"])
    d.update(change)
    if d["n_links"] == 7:
        d.update(link_lengths_pu=[1.5] + [0.2] * 7, colors=["red"] * 8)
    with pytest.raises(SpareTwinError) as err:
        ChainSpec.from_dict(json.loads(json.dumps(d)))
    assert message in str(err.value)
    assert "\n" not in str(err.value)


def test_unknown_keys_are_rejected():
    with pytest.raises(SpareTwinError, match="unknown key"):
        ChainSpec.from_dict(dict(n_links=1, link_lengths_pu=[1.5, 0.5], colors=["red", "blue"], lenghts=[1]))


def test_sampling_rejects_a_negative_seed_naming_the_parameter():
    with pytest.raises(SpareTwinError, match=r"^seed -1: must be a non-negative integer$"):
        sample_chain(2, seed=-1)
