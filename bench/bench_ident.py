"""Identification speed: rwlab vs a plain numpy baseline and a reference PEM.

Run:  python bench/bench_ident.py [--repeat 3]

Prints one table. Same data for every tool: ARX truth A = 1 − 1.5q⁻¹ + 0.7q⁻²,
B = q⁻¹ + 0.5q⁻², white binary input; ARMAX adds C = 1 − 0.5q⁻¹ noise.
Every tool fits the same model to the same data (the notes show the agreement).
Baselines:
- numpy lstsq: the regressor matrix built with numpy and solved by np.linalg.lstsq.
- scipy LM PEM: scipy.optimize.least_squares(method='lm') (MINPACK
  Levenberg–Marquardt) on the same ARMAX prediction error ε = (A y − B u)/C with
  the analytic Jacobian (three lfilter passes per evaluation), started from
  least-squares ARX(2,2,1) with C = 1. This is the fair "a competent scipy user"
  baseline; a finite-difference Jacobian would cost d + 1 filter passes more.
- SIPPY / sysidentpy: timed when installed (`pip install -e .[bench]`). SIPPY's
  delay argument counts samples beyond the one every strictly proper model has,
  so nk = 1 is SIPPY's theta = 0.
This is a benchmark, not a test: numbers vary with the machine's load.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from scipy.optimize import least_squares
from scipy.signal import lfilter

from rwlab.data import IOData
from rwlab.ident import armax, arx

A, B, C = [1, -1.5, 0.7], [0, 1.0, 0.5], [1, -0.5]


def make(N: int, seed: int = 0) -> IOData:
    r = np.random.default_rng(seed)
    u = r.choice([-1.0, 1.0], N)
    e = 0.3 * r.standard_normal(N)
    return IOData(u, lfilter(B, A, u) + lfilter(C, A, e), 1.0)


def best_of(fn, repeat: int):
    times, out = [], None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return min(times), out


def numpy_arx(data: IOData):
    y, u = data.y[:, 0], data.u[:, 0]
    phi = np.column_stack([-y[1:-1], -y[:-2], u[1:-1], u[:-2]])
    return np.linalg.lstsq(phi, y[2:], rcond=None)[0]


def scipy_lm_pem(data: IOData):
    """ARMAX(2,2,1,1) by MINPACK LM with the analytic Jacobian, from an ARX start."""
    y, u = data.y[:, 0], data.u[:, 0]
    theta0 = np.concatenate([numpy_arx(data), [0.0]])

    def eps(th):
        return lfilter([1, *th[:2]], [1, th[4]], y) - lfilter([0, *th[2:4]], [1, th[4]], u)

    def jac(th):
        C = [1, th[4]]
        yf, uf, ef = lfilter([1], C, y), lfilter([1], C, u), lfilter([1], C, eps(th))
        J = np.empty((len(y), 5))
        J[:, 0], J[:, 1] = np.r_[0, yf[:-1]], np.r_[0, 0, yf[:-2]]
        J[:, 2], J[:, 3] = -np.r_[0, uf[:-1]], -np.r_[0, 0, uf[:-2]]
        J[:, 4] = -np.r_[0, ef[:-1]]
        return J

    return least_squares(eps, theta0, jac=jac, method="lm").x


def sysidentpy_arx(data: IOData):
    """sysidentpy's FROLS restricted to the 4 linear ARX(2,2,1) terms, least squares."""
    from sysidentpy.basis_function import Polynomial
    from sysidentpy.model_structure_selection import FROLS
    from sysidentpy.parameter_estimation import LeastSquares

    model = FROLS(
        order_selection=False,
        n_terms=4,
        ylag=2,
        xlag=2,
        estimator=LeastSquares(),
        basis_function=Polynomial(degree=1),
    )
    model.fit(X=data.u, y=data.y)
    return model


def sippy(data: IOData, method: str):
    """SIPPY (PyPI sippy-unipi): ARX by linear least squares, ARMAX by its default ILLS."""
    from sippy_unipi import system_identification

    y, u = data.y[:, 0], data.u[:, 0]
    if method == "ARX":  # [na, nb, theta]: theta = nk − 1
        return system_identification(y, u, "ARX", ARX_orders=[2, 2, 0])
    return system_identification(y, u, "ARMAX", ARMAX_orders=[2, 2, 1, 0])


def sippy_parameters(model) -> np.ndarray:
    """a1 a2 b1 b2 (c1) from SIPPY's transfer-function coefficients."""
    den = np.ravel(model.DENOMINATOR[0][0])
    num = np.ravel(model.NUMERATOR[0][0])
    out = [den[1:3], num[-2:]]
    if hasattr(model, "NUMERATOR_H"):
        out.append(np.ravel(model.NUMERATOR_H[0][0])[1:2])
    return np.concatenate(out)


def optional_rows(cases, reference, repeat: int):
    """Time the optional peers on the same cases; note when one is not installed."""
    rows = []
    try:
        import sysidentpy  # noqa: F401

        t, _ = best_of(lambda: sysidentpy_arx(cases["arx"]), repeat)
        rows.append(("sysidentpy FROLS ARX221 N=1e6", t, "4 linear terms, least squares"))
    except ImportError:
        rows.append(("sysidentpy", float("nan"), "not installed (pip install -e .[bench])"))
    try:
        import sippy_unipi  # noqa: F401

        t, m = best_of(lambda: sippy(cases["arx"], "ARX"), repeat)
        diff = np.max(np.abs(sippy_parameters(m) - reference["arx"]))
        rows.append(("SIPPY ARX221 N=1e6", t, f"max |Δθ| vs rwlab {diff:.1e}"))
        for N in (100_000, 1_000_000):
            t, m = best_of(lambda n=N: sippy(cases[n], "ARMAX"), 1)
            diff = np.max(np.abs(sippy_parameters(m) - reference[N]))
            rows.append((f"SIPPY ARMAX2211 N={N:.0e}", t, f"ILLS; max |Δθ| vs rwlab {diff:.1e}"))
            if t > 10:  # the next size would take minutes
                break
    except ImportError:
        rows.append(("SIPPY", float("nan"), "not installed (pip install -e .[bench])"))
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args()
    rows = []

    big = make(1_000_000)
    t_np, th_np = best_of(lambda: numpy_arx(big), args.repeat)
    t_rw, m = best_of(lambda: arx(big, 2, 2, 1), args.repeat)
    diff = np.max(np.abs(m.parameters - th_np))
    rows.append(("numpy lstsq ARX221 N=1e6", t_np, "baseline"))
    rows.append(("rwlab arx ARX221 N=1e6", t_rw, f"max |Δθ| vs numpy {diff:.1e}"))

    cases = {"arx": big}
    reference = {"arx": m.parameters}
    for N in (100_000, 1_000_000):
        data = cases[N] = make(N, seed=1)
        t_rw, m = best_of(lambda d=data: armax(d, 2, 2, 1, 1), args.repeat)
        reference[N] = m.parameters
        its = m.report["iterations"]
        rows.append((f"rwlab armax ARMAX2211 N={N:.0e}", t_rw, f"{its} LM iterations"))
        t_ref, th_ref = best_of(lambda d=data: scipy_lm_pem(d), args.repeat)
        gap = np.max(np.abs(m.parameters - th_ref) / m.parameter_std)
        rows.append(
            (
                f"scipy LM PEM (analytic J) N={N:.0e}",
                t_ref,
                f"optimum gap {gap:.1e} σ; rwlab {t_ref / t_rw:.1f}× faster",
            )
        )

    rows += optional_rows(cases, reference, args.repeat)

    width = max(len(r[0]) for r in rows)
    print(f"{'case':<{width}}  {'time [s]':>9}  note")
    print("-" * (width + 40))
    for name, t, note in rows:
        print(f"{name:<{width}}  {t:9.3f}  {note}")


if __name__ == "__main__":
    main()
