import numpy as np
from hypothesis import given
from hypothesis import strategies as st
from scipy.signal import lfilter, lfilter_zi

from rwlab.ident.polynomials import filt

coefficient = st.floats(-3.0, 3.0, allow_nan=False)
polynomial = st.lists(coefficient, min_size=1, max_size=6)


@given(polynomial, polynomial, st.floats(-100.0, 100.0))
def test_a_steady_filter_starts_where_scipys_lfilter_zi_puts_it(b, a, level):
    a = [1.0 + abs(a[0]), *a[1:]]
    n = max(len(a), len(b))
    b_full, a_full = np.pad(b, (0, n - len(b))), np.pad(a, (0, n - len(a)))
    if n == 1 or abs(np.sum(a_full)) < 1e-3:  # no state, or (nearly) no equilibrium
        return
    x = level + np.sin(np.arange(40.0))
    expected = lfilter(b_full, a_full, x, zi=lfilter_zi(b_full, a_full) * x[0])[0]
    scale = 1.0 + np.max(np.abs(expected))
    np.testing.assert_allclose(filt(b, a, x), lfilter(b, a, x), atol=1e-12 * scale)
    np.testing.assert_allclose(filt(b, a, x, steady=True), expected, rtol=0, atol=1e-9 * scale)


def test_a_held_input_stays_at_the_filters_static_gain_from_the_first_sample():
    b, a = [0.0, 0.2, 0.1], [1.0, -1.2, 0.5]  # static gain 0.3 / 0.3 = 1
    np.testing.assert_allclose(filt(b, a, np.full(50, 4.0), steady=True), 4.0, rtol=1e-14)
