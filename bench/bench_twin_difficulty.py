"""How hard is paper A's identification study on the wheel twin? (issue 22)

For each wheel unit and experiment seed: a 20-minute PRBS at Ts = 0.5 s on the
simulated wheel (simulated clock), then `rwlab identify`'s study with its
defaults. Printed per record:

- ``paper``: paper A's published ARX221 (SPEC.md, Table 2) simulated from rest
  on the record's command, fit % on the validation part (last 30 %), in rpm;
- ``chosen``: the study's chosen model and its validation fit (the study's
  own preprocessing);
- ``ARX221``: the study's own ARX221 (paper A's choice), its fit and DC gain error;
- ``dc``: the chosen model's DC gain in rpm/rpm, and its error against the
  measured steady-state gain (``rwlab.ident.study.steady_state_gain``: the
  least-squares slope of settled speed against command over every PRBS hold of
  at least 30 s, the speed averaged over the hold's last 5 s);
- ``twin``: for a gain-constrained choice (``…+K``), its unconstrained twin's
  fit and DC gain error; ``K``: the gain imposed, measured on the estimation
  part's settled holds alone, ± its standard error (holds);
- ``amp val/est``: the RMS of the speed's deviation from its mean on the
  validation part over the same on the estimation part (a validation part that
  swings wider or narrower than the part the model learnt from).

Paper A reached 76.5 % on the real wheel. Usage::

    python bench/bench_twin_difficulty.py                   # units 0-3, seeds 0 and 7
    python bench/bench_twin_difficulty.py --pairs n:0 1:7 2:3 5:11   # unit:seed, n nominal
    python bench/bench_twin_difficulty.py --units 0 --seeds 0 --rate-limit --wheel ideal
"""

from __future__ import annotations

import argparse
import itertools
import tempfile
from pathlib import Path

import numpy as np

from rwlab.ident.models import PolyModel
from rwlab.ident.study import identification_study, load_study_data, steady_state_gain
from rwlab.ident.validation import fit_percent
from rwlab.testbed import ExperimentConfig, run_experiment

PAPER_ARX221 = ([1.0, -1.758, 0.7852], [0.0, 0.0275, -0.0012])  # SPEC.md, paper A Table 2


def one(unit: int | None, seed: int, rate_limit: bool, wheel: str, folder: Path) -> dict:
    cfg = ExperimentConfig(seed=seed, unit=unit, rate_limit=rate_limit, wheel=wheel)
    path = folder / f"u{unit}_s{seed}.mcap"
    run_experiment(cfg, path, force=True)
    data, _ = load_study_data(str(path))
    res = identification_study(data, nonlinear=False)
    u, y = data.u[:, 0], data.y[:, 0]
    n_est = res.est.N
    paper = PolyModel(*map(np.array, PAPER_ARX221), Ts=data.Ts, nk=1)
    y_paper = np.ravel(paper.simulate(u[:, None]))
    gain = steady_state_gain(data)["gain"]
    row = next(r for r in res.rows if r["structure"] == res.chosen_name)
    dc = row["dc_gain"]  # the deterministic part's, physical units
    arx221 = res.orders[0]
    twin = res.to_dict()["chosen"]["unconstrained_twin"]
    n_val = data.N - n_est
    rms = [float(np.std(part)) for part in (y[:n_est], y[n_est:])]
    return {
        "twin": twin,
        "anchor": res.gain_constraint,
        "amplitude": rms[1] / rms[0],
        "n_val": n_val,
        "arx221": arx221["fit_percent"],
        "arx221_dc": arx221["dc_gain_error_percent"],
        "unit": unit,
        "seed": seed,
        "paper": fit_percent(y[n_est:], y_paper[n_est:]),
        "chosen": res.chosen_name,
        "fit": row["fit_percent"],
        "dc": dc,
        "gain": gain,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--units", type=int, nargs="+", default=[0, 1, 2, 3])
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 7])
    ap.add_argument("--pairs", nargs="+", help="unit:seed pairs (unit n: nominal)")
    ap.add_argument(
        "--rate-limit", action="store_true", help="PRBS ramps at 314 rpm/s (default: steps)"
    )
    ap.add_argument("--wheel", default="rw90", choices=["rw90", "ideal"])
    args = ap.parse_args()
    print(
        f"wheel {args.wheel}, PRBS {'rate-limited' if args.rate_limit else 'steps'}, "
        "20 min at Ts = 0.5 s"
    )
    print(
        f"{'unit':>4} {'seed':>4} {'paper %':>8} {'chosen':>11} {'fit %':>7} "
        f"{'DC gain':>8} {'measured':>8} {'DC err %':>8} {'ARX221 %':>9} {'its DC err':>10} "
        f"{'twin fit':>8} {'twin err':>8} {'K (estimation holds)':>24} {'amp val/est':>11}"
    )
    if args.pairs:
        pairs = [
            (None if a == "n" else int(a), int(b)) for a, b in (p.split(":") for p in args.pairs)
        ]
    else:
        pairs = list(itertools.product(args.units, args.seeds))
    with tempfile.TemporaryDirectory() as tmp:
        for unit, seed in pairs:
            r = one(unit, seed, args.rate_limit, args.wheel, Path(tmp))
            err = 100 * (r["dc"] / r["gain"] - 1)
            name = "-" if unit is None else unit
            twin, k = r["twin"], r["anchor"]
            tw = (
                f"{twin['fit_percent']:8.2f} {twin['dc_gain_error_percent']:8.2f}"
                if twin
                else f"{'-':>8} {'-':>8}"
            )
            kk = "-" if k is None else f"{k['gain']:.4f} ± {k['gain_std']:.4f} ({k['holds']})"
            print(
                f"{name:>4} {seed:>4} {r['paper']:8.2f} {r['chosen']:>11} {r['fit']:7.2f} "
                f"{r['dc']:8.4f} {r['gain']:8.4f} {err:8.2f} {r['arx221']:9.2f} "
                f"{r['arx221_dc']:10.2f} {tw} {kk:>24} {r['amplitude']:11.3f}",
                flush=True,
            )


if __name__ == "__main__":
    main()
