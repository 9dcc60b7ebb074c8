import itertools

import numpy as np
import pytest
from scipy.signal import lfilter

from rwlab import datasets
from rwlab.data import IOData
from rwlab.errors import DataError
from rwlab.ident import arxstruc, delay_scan, delayest, selstruc, struc
from rwlab.ident.structure import StructureLoss


def _arx_data(nk, seed=0, N=2000, sigma=0.05):
    r = np.random.default_rng(seed)
    u = r.standard_normal(N)
    B = np.concatenate([np.zeros(nk), [1.0, 0.5]])
    A = [1, -1.2, 0.5]
    return IOData(u, lfilter(B, A, u) + lfilter([1], A, sigma * r.standard_normal(N)), 0.5)


@pytest.mark.parametrize("nk", [0, 1, 3, 6, 15, 20])
def test_delayest_finds_the_true_delay(nk):
    """Unaided: MATLAB's default scan nk_min..nk_min + 20 includes delays beyond 10."""
    assert delayest(_arx_data(nk, seed=nk)) == nk


def test_delay_scan_covers_matlabs_default_range_and_refuses_short_records():
    assert list(delay_scan(_arx_data(1))) == list(range(21))
    assert list(delay_scan(_arx_data(1), nk_min=5)) == list(range(5, 26))
    with pytest.raises(DataError, match="too short to scan delays up to nk_max = 20"):
        delayest(_arx_data(1, N=28))


def test_delayest_on_the_hair_dryer_is_three_samples_as_in_matlab():
    assert delayest(datasets.dryer().detrend()) == 3


def test_delay_scan_reports_every_delay_on_common_rows():
    losses = delay_scan(_arx_data(2), nk_min=0, nk_max=5)
    assert list(losses) == [0, 1, 2, 3, 4, 5]
    assert min(losses, key=losses.get) == 2
    assert all(v > 0 for v in losses.values())


def test_loss_never_increases_with_nested_orders_on_the_same_rows():
    data = _arx_data(1, seed=3)
    table = arxstruc(data, data, struc(range(1, 6), [2], [1]))
    losses = [s.loss for s in table]
    assert all(b <= a + 1e-15 for a, b in itertools.pairwise(losses))


def test_selstruc_recovers_the_true_order_with_mdl_and_aic():
    data = _arx_data(1, seed=4, N=4000)
    est, val = data.split(0.5)
    table = arxstruc(est, val, struc(range(1, 6), range(1, 6), [1]))
    assert selstruc(table, "mdl") == (2, 2, 1)
    assert selstruc(table, "aic")[:2] in {(2, 2), (2, 3), (3, 2), (3, 3)}


def test_selstruc_criteria_follow_matlabs_formulas():
    rows = [StructureLoss(1, 1, 1, 1.00, 100), StructureLoss(3, 3, 1, 0.93, 100)]
    # aic: log(V) + 2d/N  → 0.04 vs log(0.93) + 0.12 = 0.0474 → smaller model
    assert selstruc(rows, "aic") == (1, 1, 1)
    # mdl: V(1 + d log N / N) → 1.0921 vs 0.93·1.2763 = 1.187 → smaller model
    assert selstruc(rows, "mdl") == (1, 1, 1)
    assert selstruc(rows, 0) == (3, 3, 1)
    c = 0.5  # V(1 + c d / N): 1.01 vs 0.9579 → larger model
    assert selstruc(rows, c) == (3, 3, 1)


def test_structure_functions_reject_bad_arguments():
    data = _arx_data(1)
    with pytest.raises(DataError):
        delayest(data, nk_min=5, nk_max=2)
    with pytest.raises(DataError):
        arxstruc(data, data, [])
    with pytest.raises(DataError):
        selstruc(arxstruc(data, data, [(2, 2, 1)]), "bic")
    with pytest.raises(DataError):
        delayest(IOData(np.ones((10, 2)), np.ones(10), 1.0))
