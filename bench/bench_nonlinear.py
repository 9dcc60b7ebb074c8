"""Nonlinear wheel models on one PRBS record of the simulated RW90: fit and residual whiteness.

Rows: paper A's chosen linear model (the study's ARX221), the same model wrapped
with the record's limits as ``IdentifiedWheel`` flew it before (Hammerstein–Wiener
form, limits copied, not estimated), rwlab's servo model, and a polynomial NARX
from sysidentpy (FROLS, degree 2), simulated free-run on the same validation part.

sysidentpy pins an older numpy, so it never goes into rwlab's environment: give
the Python of a separate venv (``python -m venv /tmp/sysidenv &&
/tmp/sysidenv/bin/pip install sysidentpy``); it gets the data as a .npz.

    python bench/bench_nonlinear.py [--minutes 25] [--seed 0] [--sysidentpy VENV/bin/python]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import tempfile
import time
from pathlib import Path

import numpy as np

from rwlab.ident import arx, fit_percent
from rwlab.ident.study import identification_study
from rwlab.testbed import ExperimentConfig, load_record, run_experiment
from rwlab.wheel import IdentifiedWheel

NARX = """
import json, sys, time
import numpy as np
from sysidentpy.basis_function import Polynomial
from sysidentpy.model_structure_selection import FROLS
z = np.load(sys.argv[1])
t = time.perf_counter()
m = FROLS(order_selection=True, n_info_values=15, ylag=2, xlag=2, info_criteria="aic",
          basis_function=Polynomial(degree=2))
m.fit(X=z["ue"][:, None], y=z["ye"][:, None])
yhat = m.predict(X=z["uv"][:, None], y=z["yv"][:2, None])[:, 0]
print(json.dumps({"yhat": yhat.tolist(), "seconds": time.perf_counter() - t,
                  "terms": int(m.final_model.shape[0])}))
"""


def _acf_max(e: np.ndarray, lags: int = 25) -> float:
    e = e - e.mean()
    r = np.correlate(e, e, "full")[e.size - 1 : e.size + lags]
    return float(np.max(np.abs(r[1:] / r[0])))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--minutes", type=float, default=25.0)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--sysidentpy", help="python of a venv with sysidentpy installed")
    args = ap.parse_args()

    with tempfile.TemporaryDirectory() as tmp:
        record = Path(tmp) / "prbs.mcap"
        run_experiment(ExperimentConfig(duration=60 * args.minutes, seed=args.seed), record)
        data = load_record(record)
        t = time.perf_counter()
        study = identification_study(data, limits_rpm=(7800.0, 7800.0))
        seconds = time.perf_counter() - t
        s = study.to_dict()
        val, trend = study.physical_val, study.data.trend
        y = val.y[:, 0]
        rows = []
        y_lin = trend.output_to_physical(
            study.chosen.simulate(study.val, initial="steady"), study.val.time
        )
        res = s["residuals"][s["chosen"]["structure"]]
        rows.append(
            (
                f"linear {s['chosen']['structure']} (paper A)",
                s["chosen"]["fit_percent"],
                max(abs(a) for a in res["acf"][1:]),
                _acf_max(y - y_lin),
                "—",
                seconds,
            )
        )
        # the same structure on the physical (not normalised) data
        est = data.split(0.7)[0]
        phys = arx(est, 2, 2, 1)
        y_phys = phys.simulate(val, initial="steady")
        e_pred = y - phys.predict(val, 1, initial="steady")
        rows.append(
            (
                "ARX221 on physical units",
                fit_percent(y, y_phys),
                _acf_max(e_pred),
                _acf_max(y - y_phys),
                "—",
                None,
            )
        )
        # the Hammerstein–Wiener wrapping with copied limits, as IdentifiedWheel flew it
        from rwlab.ident.study import physical_model

        info = physical_model(study)
        model_file = Path(tmp) / "model.json"
        model_file.write_text(json.dumps(info))
        hw = IdentifiedWheel.from_json(model_file, model="linear")
        hw.reset(float(y[0]))
        y_hw = np.r_[y[0], [hw.step(c) for c in val.u[:-1, 0]]]
        rows.append(
            (
                "linear + copied limits (HW)",
                fit_percent(y, y_hw),
                None,
                _acf_max(y - y_hw),
                "314 (copied)",
                0.0,
            )
        )
        nl = s["nonlinear"]
        y_nl = study.servo.predict(val, initial="steady")
        rows.append(
            (
                "rwlab servo (nonlinear)",
                nl["fit_percent"],
                max(abs(a) for a in nl["residuals"]["acf"][1:]),
                _acf_max(y - y_nl),
                f"{nl['accel_limit_rpm_s']:.1f}",
                None,
            )
        )
        if args.sysidentpy:
            npz = Path(tmp) / "z.npz"
            np.savez(npz, ue=est.u[:, 0], ye=est.y[:, 0], uv=val.u[:, 0], yv=val.y[:, 0])
            out = subprocess.run(
                [args.sysidentpy, "-c", NARX, str(npz)], capture_output=True, text=True, check=True
            )
            narx = json.loads(out.stdout.strip().splitlines()[-1])
            y_narx = np.asarray(narx["yhat"])
            rows.append(
                (
                    f"sysidentpy NARX, {narx['terms']} terms",
                    fit_percent(y, y_narx),
                    None,
                    _acf_max(y - y_narx),
                    "—",
                    narx["seconds"],
                )
            )
    print(f"{args.minutes:g}-min PRBS, seed {args.seed}, validation = last 30 %, 'steady' start")
    print(f"{'model':<34} {'fit %':>7} {'resid acf':>10} {'sim-err acf':>12} {'α rpm/s':>13}")
    for name, fit, acf, sim_acf, alpha, _ in rows:
        acf_s = "—" if acf is None else f"{acf:.3f}"
        print(f"{name:<34} {fit:7.2f} {acf_s:>10} {sim_acf:12.3f} {alpha:>13}")
    print("resid acf: max |acf| over lags 1–25 of the residuals study.json reports (linear:")
    print("one-step prediction errors; servo: simulation errors from an estimated initial state);")
    print("sim-err acf: the same of the free-run simulation error from the 'steady' start.")
    print(f"study incl. the servo fit: {rows[0][5]:.1f} s")


if __name__ == "__main__":
    main()
