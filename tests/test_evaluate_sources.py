"""`spare-twin evaluate` reports where its figures come from: the network alone (the headline) and,
where a measurement stands beside it, the answer predict gives (the network overruled by the
measurement); shipped cards and models/index.json lead with the network's own figure."""

import json
from dataclasses import asdict

import numpy as np
import pytest
import torch
from conftest import refused_before_torch, run_cli

from spare_twin.nets import checkpoint as ckpt
from spare_twin.nets.evaluate import Evaluation, evaluation_of
from spare_twin.nets.presets import get_preset
from spare_twin.predict.evaluate import SourcesEvaluation, combined_evaluation, recorded

#: Four test instances with 1..4 moving links; every link 0.5 long past a 1.5 base.
TRUE_N = np.array([1, 2, 3, 4])
TRUE_LENGTHS = np.array([[1.5] + [0.5] * n + [0.0] * (6 - n) for n in TRUE_N], np.float32)


def _network_says_one_link() -> Evaluation:
    """A network that answers n = 1 (base 1.5, link 0.5) for all four, unsure (no count above 0.4),
    beside a measurement that found the chains of instances 0, 1 and 3 exactly and none in 2."""
    probabilities = np.tile(np.array([0.4, 0.2, 0.1, 0.1, 0.1, 0.1], np.float32), (4, 1))
    net_lengths = np.tile(np.array([1.5, 0.5, 0, 0, 0, 0, 0], np.float32), (4, 1))
    measured_n = np.array([1, 2, 0, 4])
    pred = {
        "pred_n": np.ones(4, np.int64),
        "probabilities": probabilities,
        "lengths_e2e": net_lengths,
        "lengths_known": TRUE_LENGTHS.copy(),  # the network's n-known lengths: exact here
        "true_n": TRUE_N,
        "true_lengths": TRUE_LENGTHS,
        "measured_n": measured_n,
        "measured_lengths_pu": TRUE_LENGTHS * (measured_n > 0)[:, None],
        "measured_angles_rad": np.zeros((4, 6), np.float32),
    }
    return evaluation_of(pred, "test", "m.pt", "profile-depth-multitask", "data")


def test_the_combined_answer_is_the_network_overruled_where_the_measurement_found_a_chain():
    network = _network_says_one_link()
    assert network.count_accuracy == 0.25  # only the 1-link instance
    # the network's end-to-end error: the links it missed, 0.5^2 each (1, 2 and 3 of them)
    assert network.E_L == pytest.approx((0 + 0.25 + 0.5 + 0.75) / 4)
    combined = combined_evaluation(network)
    # measured chains replace the answer (instances 0, 1, 3); instance 2 keeps the network's n = 1
    assert combined.count_accuracy == 0.75
    assert combined.confusion_matrix[2][0] == 1 and combined.confusion_matrix[3][3] == 1
    assert combined.E_L == pytest.approx(0.5 / 4)  # instance 2's two missing links, nothing else
    assert combined.E_L_n_known is None and network.E_L_n_known == 0.0  # n known: the network's alone
    assert combined.per_n["3"]["count_accuracy"] == 0.0 and combined.per_n["4"]["count_accuracy"] == 1.0


def test_a_network_without_a_measurement_has_no_combined_figure():
    network = _network_says_one_link()
    alone = evaluation_of(
        {k: v for k, v in network.predictions.items() if not k.startswith("measured_")}, "test", "m", "p", "d"
    )
    assert combined_evaluation(alone) is None
    out = SourcesEvaluation(alone, None).to_json()
    assert out["combined"] is None and "network alone" in out["combined_reason"]


def test_the_headline_is_the_network_and_the_card_leads_with_it():
    network = _network_says_one_link()
    result = SourcesEvaluation(network, combined_evaluation(network))
    out = result.to_json()
    assert list(out)[:5] == ["count_accuracy", "E_L", "instances", "split", "headline"]
    assert out["headline"] == "network" and out["count_accuracy"] == out["network"]["count_accuracy"] == 0.25
    assert out["combined"]["count_accuracy"] == 0.75 and out["E_L"] == out["network"]["E_L"]
    metrics = recorded(result)
    keys = list(metrics)
    assert keys.index("count_accuracy") < keys.index("with_measurement_count_accuracy") < keys.index("instances")
    assert metrics["with_measurement_count_accuracy"] == 0.75 and "with_measurement_E_L_n_known" not in metrics
    # models/index.json sorts its keys: the network's figures come first there too
    assert sorted(metrics).index("count_accuracy") < sorted(metrics).index("with_measurement_count_accuracy")
    p = get_preset("profile-depth-multitask")
    ck = {"preset": p.name, "net": asdict(p.net), "train": asdict(p.train), "meta": {"metrics": metrics}}
    card = ckpt.model_card(ck, "profile-multitask")
    assert card.index("| count_accuracy | 0.2500 |") < card.index("| with_measurement_count_accuracy | 0.7500 |")


@pytest.fixture(scope="module")
def untrained_geo(tmp_path_factory):
    """A synthetic multi-view set and an untrained small voxel counter saved as a checkpoint."""
    from spare_twin.dataset.synthetic import SyntheticSpec, write_synthetic
    from spare_twin.nets.presets import resolve
    from spare_twin.nets.registry import build_model

    root = tmp_path_factory.mktemp("sources")
    data = write_synthetic(root / "syn", SyntheticSpec(sizes=(("train", 4), ("val", 4), ("test", 12)), seed=5))
    preset = resolve("geo-depth-mv-count", {"net": {"channels": [4, 8], "fc_hidden": 16}})
    torch.manual_seed(0)
    model = build_model(preset.net)
    path = ckpt.save(root / "geo.pt", ckpt.model_record(preset.name, preset.net, preset.train, model, {}))
    return data, path


def test_evaluate_json_of_a_network_with_no_measurement_beside_it(untrained_geo, tmp_path, capsys):
    data, model = untrained_geo
    argv = ["evaluate", "--model", str(model), "--data", str(data), "--out", str(tmp_path / "ev"), "--json"]
    code, out, err = run_cli(argv, capsys)
    assert code == 0, err
    res = json.loads(out)
    assert res["instances"] == 12 and res["split"] == "test" and res["headline"] == "network"
    assert res["combined"] is None and res["combined_reason"]
    assert res["count_accuracy"] == res["network"]["count_accuracy"] and res["E_L"] is None  # a counter
    assert sum(np.asarray(res["network"]["confusion_matrix"]).ravel()) == 12
    written = json.loads((tmp_path / "ev" / "evaluation.json").read_text())
    assert written["network"] == res["network"] and written["combined"] is None
    assert (tmp_path / "ev" / "confusion_matrix.png").is_file()
    assert not (tmp_path / "ev" / "confusion_matrix_combined.png").exists()


def test_a_missing_checkpoint_or_data_folder_is_said_before_torch_is_loaded(tmp_path):
    """A missing checkpoint or data folder, a count below 1, an output that is not evaluate's or a
    name `--ship` cannot take: said before the evaluation's modules (torch and the network: 5 s of a
    new process) are imported, and nothing written."""
    (tmp_path / "data").mkdir()
    (tmp_path / "mine").mkdir()
    (tmp_path / "mine" / "notes.txt").write_text("mine")
    cases = [
        (["--model", "nope.pt", "--data", "data"], ("nope.pt", "no such checkpoint")),
        (["--data", "nope"], ("--data nope", "no such folder")),
        (["--model", "nope.pt", "--data", "nope"], ("nope.pt",)),
        (["--data", "data", "--batch-size", "0"], ("--batch-size 0",)),
        (["--data", "data", "--max-samples", "0"], ("--max-samples 0",)),
        (["--data", "data", "--default-for", "predict"], ("--default-for", "ship")),
        (["--data", "data", "--ship", "../x"], ("--ship '../x'", "file stem")),
        (["--data", "data", "--ship", "m", "--default-for", "nope"], ("--default-for", "unknown task 'nope'")),
    ]
    argvs = [(["evaluate", *args, "--out", "ev"], words) for args, words in cases]
    argvs += [
        (["evaluate", "--data", "data", "--out", "mine"], ("mine", "--force")),
        (["evaluate", "--data", "data", "--out", "data/ev"], ("data/ev", "inside the input")),
    ]
    refused_before_torch(argvs, tmp_path)
