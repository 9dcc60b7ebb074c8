"""Nonlinear wheel models judged on wheel units they were not identified on (issue 22).

One 20-minute PRBS record (Ts = 0.5 s, paper A's steps: the default) of twin unit ``--unit``
is studied as ``rwlab identify`` does (its ``model.json``: the linear model,
the servo model, the grey-box wheel, the NLARX). Then every model is scored
by ``rwlab compare``'s function (simulation from the record's first speed, the
record's saturations applied) on records of *other* units, other seeds:

- ``unit B``: a nominal unit, the default (stepped) PRBS;
- ``unit B, ramps``: the same unit, the PRBS rate-limited to 314 rpm/s (``--rate-limit``);
- ``unit B, ±300 rpm``: the same unit at low speed (friction, Hall quantisation);
- ``unit C, 0.35 A``: a unit whose driver limits the current to 0.35 A, so the
  current limit binds in every fast transient (it cannot reach 314 rpm/s).

The last column is sysidentpy's polynomial NARX (FROLS, degree 2, ylag = xlag = 2,
AIC term selection), fitted on the same estimation part of unit A and simulated
free-run on the same records. sysidentpy pins an older numpy, so it runs in a
separate venv (``python -m venv /tmp/sysidenv && /tmp/sysidenv/bin/pip install
sysidentpy``) and gets the data as .npz.

    python bench/bench_nonlinear.py [--unit 1] [--sysidentpy /tmp/sysidenv/bin/python]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from rwlab.ident import fit_percent
from rwlab.ident.study import identification_study, load_current, load_study_data, physical_model
from rwlab.testbed import ExperimentConfig, run_experiment
from rwlab.wheel import RW90
from rwlab.wheel.compare import compare_wheel_models

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
fit_s = time.perf_counter() - t
out = {"seconds": fit_s, "terms": int(m.final_model.shape[0]), "yhat": {}}
for k in z.files:
    if k.startswith("u_"):
        name = k[2:]
        y = z["y_" + name]
        yhat = m.predict(X=z[k][:, None], y=y[:2, None])[:, 0]
        out["yhat"][name] = yhat.tolist()
print(json.dumps(out))
"""

RECORDS = {
    "unit B": dict(seed=11, unit=2),
    "unit B, ramps": dict(seed=12, unit=2, rate_limit=True),
    "unit B, ±300 rpm": dict(seed=13, unit=2, amplitude=300.0),
    "unit C, 0.35 A": dict(seed=23, unit=3),
}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--unit", type=int, default=1, help="the unit identified on")
    ap.add_argument("--seed", type=int, default=3)
    ap.add_argument("--sysidentpy", help="python of a venv with sysidentpy installed")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        ident = root / "unit_a.mcap"
        run_experiment(
            ExperimentConfig(duration=1200, Ts=0.5, seed=args.seed, unit=args.unit), ident
        )
        data, sat = load_study_data(str(ident))
        t = time.perf_counter()
        study = identification_study(
            data,
            limits_rpm=(sat["speed_limit_rpm"],) * 2,
            datasheet={"current_limit": sat["current_limit_a"]},
            current=load_current(str(ident)),
        )
        seconds = time.perf_counter() - t
        model = root / "model.json"
        model.write_text(json.dumps(physical_model(study)))
        grey = study.greybox
        print(f"identified on twin unit {args.unit}, seed {args.seed} ({seconds:.0f} s, study)")
        print(f"chosen linear model: {study.reason}")
        print(f"chosen nonlinear model: {study.nonlinear['choice']}")
        print("grey box (J fixed at the datasheet 4.2e-4 kg·m²), estimate ± std:")
        for k, v in grey.std.items():
            print(f"  {k:<16} {getattr(grey, k):.5g} ± {v:.2g}")
        for k in grey.unidentified:
            print(f"  {k:<16} {getattr(grey, k):.5g}  (not identified by this record)")
        scores, npz = {}, {}
        est = data.split(0.7)[0]
        npz["ue"], npz["ye"] = est.u[:, 0], est.y[:, 0]
        i = 0
        for name, options in RECORDS.items():
            path = root / f"{name.replace(' ', '_').replace(',', '')}.mcap"
            params = replace(RW90, current_limit=0.35) if "0.35" in name else None
            cfg = ExperimentConfig(duration=1200, Ts=0.5, **options)
            run_experiment(cfg, path, params=params)
            rec, rec_sat = load_study_data(str(path))
            scores[name] = compare_wheel_models(model, rec, rec_sat)
            npz[f"u_{i}"], npz[f"y_{i}"] = rec.u[:, 0], rec.y[:, 0]
            scores[name]["_y"] = rec.y[:, 0]
            i += 1
        narx = None
        if args.sysidentpy:
            np.savez(root / "z.npz", **npz)
            out = subprocess.run(
                [args.sysidentpy, "-c", NARX, str(root / "z.npz")],
                capture_output=True,
                text=True,
                check=True,
            )
            narx = json.loads(out.stdout.strip().splitlines()[-1])
    names = ["linear", "servo", "greybox", "nlarx"]
    head = f"{'record':<18}" + "".join(f"{n:>9}" for n in names)
    chosen = study.nonlinear["chosen"]
    head += f"{'NARX(sysidentpy)':>18}{chosen + ' − linear':>17}"
    print("\nsimulated fit % (rwlab compare), whole record, from its first speed")
    print(head)
    for i, (name, row) in enumerate(scores.items()):
        line = f"{name:<18}" + "".join(f"{row[n]['fit_percent']:9.2f}" for n in names)
        if narx is not None:
            yhat = np.asarray(narx["yhat"][str(i)], dtype=float)
            ok = np.all(np.isfinite(yhat))
            line += f"{fit_percent(row['_y'], yhat):18.2f}" if ok else f"{'diverged':>18}"
        else:
            line += f"{'—':>18}"
        gain = row[chosen]["fit_percent"] - row["linear"]["fit_percent"]
        print(line + f"{gain:17.2f}")
    if narx is not None:
        print(f"sysidentpy NARX: {narx['terms']} terms, fitted in {narx['seconds']:.2f} s")


if __name__ == "__main__":
    main()
