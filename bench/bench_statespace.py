"""State-space identification speed: rwlab's n4sid vs SIPPY's N4SID, ssest vs a scipy PEM.

Run:  python bench/bench_statespace.py [--sizes 1e4,1e5,1e6] [--sippy-python PY]

Prints one table. Data: the 2-input 2-output 4th-order innovations-form system
of tests/test_statespace.py (poles 0.7 ± 0.4j, 0.85, 0.3), white Gaussian
inputs, innovations of standard deviation 0.1.

- n4sid vs SIPPY: both with the N4SID weighting, order 4, future and past
  horizons 20 (SIPPY's default SS_f), no feedthrough. SIPPY (sippy-unipi)
  pins an old numpy, so it runs in its own interpreter given by
  ``--sippy-python`` (e.g. a venv made with
  ``python -m venv /tmp/sippyenv && /tmp/sippyenv/bin/pip install sippy-unipi``);
  the data go to it through an .npz file and only its N4SID call is timed.
  "pole gap" is the largest distance between the two tools' poles after
  matching; "pole error" is rwlab's distance to the true poles.
- ssest vs a scipy PEM at N = 3000: ``scipy.optimize.least_squares`` over every
  entry of A, B, C, K (no reduction of the similarity redundancy), with the
  predictor simulated by ``scipy.signal.dlsim``, from the same n4sid start.
  This is what a competent scipy user writes without rwlab.
This is a benchmark, not a test: numbers vary with the machine's load.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import tempfile
import time
from pathlib import Path

import numpy as np
from scipy import optimize
from scipy import signal as sps
from scipy.optimize import linear_sum_assignment

from rwlab.data import IOData
from rwlab.ident import SSModel, n4sid, ssest

A = np.array([[0.7, 0.4, 0, 0], [-0.4, 0.7, 0, 0], [0, 0, 0.85, 0], [0, 0, 0, 0.3]])
B = np.array([[1.0, 0.0], [0.5, 0.3], [0.0, 1.0], [0.8, -0.6]])
C = np.array([[1.0, 0.0, 1.0, 0.5], [0.0, 1.0, -0.5, 1.0]])
K = np.array([[0.3, 0.1], [0.0, 0.2], [0.2, -0.1], [0.1, 0.3]])
TRUE_POLES = np.linalg.eigvals(A)
HORIZON = 20

SIPPY_SCRIPT = """
import json, sys, time
import numpy as np
from sippy_unipi import system_identification
z = np.load(sys.argv[1])
t0 = time.perf_counter()
m = system_identification(z["y"].T, z["u"].T, "N4SID", SS_fixed_order=4, SS_f=int(z["f"]),
                          tsample=float(z["Ts"]))
t = time.perf_counter() - t0
p = np.linalg.eigvals(np.asarray(m.A))
print(json.dumps({"time": t, "poles_re": p.real.tolist(), "poles_im": p.imag.tolist()}))
"""


def make(N: int, seed: int = 0) -> IOData:
    rng = np.random.default_rng(seed)
    u = rng.standard_normal((N, 2))
    e = 0.1 * rng.standard_normal((N, 2))
    model = SSModel(A, np.hstack([B, K]), C, np.hstack([np.zeros((2, 2)), np.eye(2)]), Ts=1.0)
    y = model.simulate(np.hstack([u, e]))  # x⁺ = A x + B u + K e, y = C x + e
    return IOData(u, y, 1.0)


def gap(p: np.ndarray, q: np.ndarray) -> float:
    dist = np.abs(p[:, None] - q[None, :])
    r, c = linear_sum_assignment(dist)
    return float(dist[r, c].max())


def run_sippy(python: str, data: IOData, timeout: float) -> dict | str:
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "data.npz"
        np.savez(path, u=data.u, y=data.y, Ts=data.Ts, f=HORIZON)
        try:
            out = subprocess.run(
                [python, "-c", SIPPY_SCRIPT, str(path)],
                capture_output=True,
                text=True,
                timeout=timeout,
            )
        except subprocess.TimeoutExpired:
            return f"> {timeout:g} s (stopped)"
        if out.returncode:
            return "failed: " + (out.stderr.strip().splitlines() or ["?"])[-1][:60]
        res = json.loads(out.stdout.strip().splitlines()[-1])
        res["poles"] = np.array(res["poles_re"]) + 1j * np.array(res["poles_im"])
        return res


def scipy_pem(data: IOData, start: SSModel, max_nfev: int) -> tuple[float, np.ndarray, float]:
    """Full-parameter PEM with scipy's dlsim predictor (initial state zero)."""
    n, nu, ny = start.nx, start.nu, start.ny
    sizes = [n * n, n * nu, ny * n, n * ny]
    w = np.hstack([data.u, data.y])

    def unpack(th):
        parts = np.split(th, np.cumsum(sizes)[:-1])
        return parts[0].reshape(n, n), parts[1].reshape(n, nu), parts[2].reshape(ny, n), \
            parts[3].reshape(n, ny)  # fmt: skip

    def residuals(th):
        a, b, c, k = unpack(th)
        pred = (a - k @ c, np.hstack([b, k]), c, np.zeros((ny, nu + ny)), data.Ts)
        _, yhat, _ = sps.dlsim(pred, w)
        r = (data.y - yhat).ravel()
        return r if np.all(np.isfinite(r)) else np.full(r.shape, 1e10)

    th0 = np.concatenate([start.A.ravel(), start.B.ravel(), start.C.ravel(), start.K.ravel()])
    t0 = time.perf_counter()
    sol = optimize.least_squares(residuals, th0, method="trf", max_nfev=max_nfev)
    t = time.perf_counter() - t0
    e = sol.fun.reshape(-1, ny)
    return t, np.linalg.eigvals(unpack(sol.x)[0]), float(np.linalg.det(e.T @ e / len(e)))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="1e4,1e5,1e6", help="Record lengths N, comma separated.")
    ap.add_argument("--sippy-python", help="Interpreter with sippy-unipi installed.")
    ap.add_argument("--sippy-timeout", type=float, default=600.0, help="Seconds per SIPPY run.")
    ap.add_argument("--pem-nfev", type=int, default=400, help="Evaluation cap of the scipy PEM.")
    args = ap.parse_args()
    sizes = [int(float(s)) for s in args.sizes.split(",")]
    horizon = (HORIZON, HORIZON, HORIZON)
    n4sid(make(1000), 4, horizon=horizon)  # compile the numba predictor once

    print("n4sid (N4SID weighting, order 4, horizons 20) vs SIPPY N4SID")
    print(
        f"{'N':>9} {'rwlab s':>9} {'SIPPY s':>12} {'speed-up':>9} {'pole gap':>9} {'pole err':>9}"
    )
    for N in sizes:
        data = make(N)
        t0 = time.perf_counter()
        m = n4sid(data, 4, weighting="N4SID", horizon=horizon, initial="zero")
        t_rw = time.perf_counter() - t0
        err = gap(m.poles(), TRUE_POLES)
        sippy = (
            run_sippy(args.sippy_python, data, args.sippy_timeout) if args.sippy_python else None
        )
        if isinstance(sippy, dict):
            g = gap(m.poles(), sippy["poles"])
            cells = f"{sippy['time']:12.3f} {sippy['time'] / t_rw:8.1f}x {g:9.2e}"
        else:
            cells = f"{sippy or 'not run':>12} {'':>9} {'':>9}"
        print(f"{N:>9} {t_rw:9.3f} {cells} {err:9.2e}", flush=True)

    data = make(3000, seed=1)
    start = n4sid(data, 4)
    t0 = time.perf_counter()
    ms = ssest(data, start, initial="zero")
    t_ss = time.perf_counter() - t0
    t_sp, p_sp, loss_sp = scipy_pem(data, start, args.pem_nfev)
    e0 = start.residuals(data, initial="zero")
    loss0 = float(np.linalg.det(e0.T @ e0 / len(e0)))
    print("\nssest vs scipy least_squares PEM (N = 3000, same n4sid start, x0 = 0)")
    print(f"{'tool':>14} {'seconds':>9} {'loss det(Λ)':>12} {'pole err':>9}")
    rows = [
        ("rwlab ssest", f"{t_ss:9.3f}", ms.report["loss"], ms.poles()),
        ("scipy PEM", f"{t_sp:9.3f}", loss_sp, p_sp),
        ("n4sid start", f"{'':>9}", loss0, start.poles()),
    ]
    for name, t, loss, poles in rows:
        print(f"{name:>14} {t} {loss:12.4e} {gap(poles, TRUE_POLES):9.2e}")


if __name__ == "__main__":
    main()
