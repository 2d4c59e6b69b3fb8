"""The paper's metrics against hand-worked examples."""

import cv2
import numpy as np
import pytest

from spare_twin.nets import metrics, plots


def test_count_accuracy():
    assert metrics.count_accuracy([1, 2, 3, 4], [1, 2, 4, 4]) == 0.75
    with pytest.raises(ValueError):
        metrics.count_accuracy([1, 2], [1])


def test_e_l_right_count_sums_squared_slot_errors():
    # n = 2: base 1.5, links 0.5 and 0.8; predicted 1.4, 0.6, 0.8 and junk past the count (ignored)
    t = np.array([[1.5, 0.5, 0.8, 0, 0, 0, 0]])
    p = np.array([[1.4, 0.6, 0.8, 9.0, 9.0, 9.0, 9.0]])
    # 0.1^2 + 0.1^2 + 0 = 0.02
    assert metrics.length_errors(t, p, [2], [2]) == pytest.approx([0.02])


def test_e_l_count_too_low_adds_the_missed_links():
    # true n = 3 (1.5, 0.5, 0.8, 0.4); predicted n = 2 with exact lengths: the missing link 0.4 costs 0.16
    t = np.array([[1.5, 0.5, 0.8, 0.4, 0, 0, 0]])
    p = np.array([[1.5, 0.5, 0.8, 0.4, 0, 0, 0]])
    assert metrics.length_errors(t, p, [3], [2]) == pytest.approx([0.16])


def test_e_l_count_too_high_adds_the_invented_links():
    # true n = 1 (2.0, 1.0); predicted n = 3 (2.0, 0.9, 0.3, 0.2): 0.01 + 0.09 + 0.04 = 0.14
    t = np.array([[2.0, 1.0, 0, 0, 0, 0, 0]])
    p = np.array([[2.0, 0.9, 0.3, 0.2, 0.7, 0, 0]])
    assert metrics.length_errors(t, p, [1], [3]) == pytest.approx([0.14])


def test_e_l_n_known_uses_the_true_count_for_both_and_mean_over_instances():
    t = np.array([[1.5, 0.5, 0.8, 0.4, 0, 0, 0], [2.0, 1.0, 0, 0, 0, 0, 0]])
    p = np.array([[1.5, 0.5, 0.8, 0.0, 0, 0, 0], [1.0, 1.0, 5.0, 0, 0, 0, 0]])
    # instance 0: 0.4^2 = 0.16; instance 1: 1.0^2 = 1.0 (slot 2 masked); mean 0.58
    assert metrics.length_errors(t, p, [3, 1]) == pytest.approx([0.16, 1.0])
    # end-to-end with predicted counts 3 and 2: instance 1 now pays slot 2 as well: 1 + 25
    assert metrics.length_errors(t, p, [3, 1], [3, 2]) == pytest.approx([0.16, 26.0])


def test_confusion_matrix_and_per_n():
    cm = metrics.confusion_matrix([1, 1, 2, 6, 6, 6], [1, 2, 2, 6, 6, 5])
    assert cm.shape == (6, 6) and cm.sum() == 6
    assert cm[0, 0] == 1 and cm[0, 1] == 1 and cm[1, 1] == 1 and cm[5, 5] == 2 and cm[5, 4] == 1
    per = metrics.per_n_breakdown([1, 1, 2, 6, 6, 6], [1, 2, 2, 6, 6, 5], np.array([0.0, 1.0, 0.5, 0.1, 0.2, 0.3]))
    assert set(per) == {"1", "2", "6"}
    assert per["1"] == {"instances": 2, "count_accuracy": 0.5, "E_L": 0.5}
    assert per["6"]["count_accuracy"] == pytest.approx(2 / 3) and per["6"]["E_L"] == pytest.approx(0.2)
    with pytest.raises(ValueError):
        metrics.confusion_matrix([0], [1])


def test_pngs_are_written(tmp_path):

    png = plots.write_confusion_png(np.eye(6, dtype=int) * 3, tmp_path / "cm.png")
    img = cv2.imread(str(png))
    assert img is not None and img.shape[0] > 300 and img.std() > 10
    hist = [{"epoch": i + 1, "train_loss": 1.0 / (i + 1), "val_count_accuracy": 0.2 + 0.1 * i} for i in range(5)]
    img = cv2.imread(str(plots.write_learning_curve_png(hist, tmp_path / "lc.png")))
    assert img is not None and img.std() > 10
