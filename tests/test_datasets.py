from pathlib import Path

import numpy as np

from rwlab import datasets

DATA_DIR = Path(__file__).parent / "data"


def test_bundled_dryer_matches_matlabs_dryer2_copy():
    d = datasets.dryer()
    other = np.loadtxt(DATA_DIR / "matlab_dryer2_u2_y2.csv", delimiter=",")
    assert d.N == 1000 and d.Ts == 0.08
    assert np.max(np.abs(d.u[:, 0] - other[:, 0])) < 1e-7
    assert np.max(np.abs(d.y[:, 0] - other[:, 1])) < 1e-7


def test_other_bundled_sets_have_their_documented_shapes():
    assert datasets.gas_furnace().N == 296 and datasets.gas_furnace().Ts == 9.0
    est, val = datasets.cascaded_tanks()
    assert est.N == val.N == 1024 and est.Ts == 4.0
    assert datasets.drive(3).N == 500 and datasets.drive(3).Ts == 0.02
