"""False alarms on request: the GLR pipeline's rates on healthy records it was not calibrated on.

Run:  python bench/bench_fdi_rates.py --wheel W --cache DIR --model model.json \
          --calibrate tune_h0 ... tune_h5 --judge w5_h0 w5_h1 ... [--rates 1 10 100]

The calibration is measured on the ``--calibrate`` records (healthy, as ``bench_fdi.py``);
each model-based detector's threshold for each asked rate is taken from it, and the
excursions of its statistic above that threshold are counted on the ``--judge`` records
(healthy, other units and seeds), as the calibration counts them on its own
(``excursion_peaks``). Prints, per detector and rate, the asked and measured rates with
the measured rate's Garwood 95 % interval, and how many cells lie within ×2 of the rate
asked. A cell is "unreachable" where the detector's statistic rose above its floor less
than half as often as asked on the calibration records (no threshold gives that rate), or
where the judged hours hold less than one alarm at half the rate. Records are read from
``--cache`` by name (made by ``bench_fdi.py --make``). A benchmark, not a test.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from bench_fdi import record_arguments, record_features
from rwlab.diagnose.bank import Bank
from rwlab.diagnose.detectors import MODEL_BASED
from rwlab.diagnose.features import WheelScales
from rwlab.diagnose.wheel_calibration import DiagnosisCalibration, excursion_peaks, garwood
from rwlab.wheel import IdentifiedWheel


def main() -> None:
    p = record_arguments(__doc__.splitlines()[0])
    p.add_argument("--rates", nargs="+", type=float, default=[1.0, 10.0, 100.0])
    args = p.parse_args()
    scales = WheelScales.from_model_file(args.model)
    wheel = IdentifiedWheel.from_json(args.model)

    def features(name: str):
        return record_features(args.cache / f"{name}.mcap", wheel, scales)

    cal = DiagnosisCalibration.measure([features(n) for n in args.calibrate])
    peaks: dict[str, list[float]] = {n: [] for n in MODEL_BASED}
    hours = 0.0
    for name in args.judge:
        f = features(name)
        hours += f.N * scales.Ts / 3600
        bank = Bank(f, cal.noise, cal.zones, cal.drift, cal.dispersion)
        for detector, stat in bank.statistics().items():
            peaks[detector] += excursion_peaks(stat)
    print(
        f"{args.wheel}: calibrated on {cal.hours:.2f} h, judged on {hours:.2f} h "
        f"({len(args.judge)} healthy records)"
    )
    print(f"{'detector':18s} {'asked/h':>8s} {'threshold':>10s} {'measured/h':>10s}  95 % interval")
    within = reachable = 0
    for detector in MODEL_BASED:
        for rate in args.rates:
            threshold = cal.threshold(detector, rate)
            n = int(np.sum(np.array(peaks[detector]) > threshold.log_lr))
            lo, hi = garwood(n, hours)
            measured = n / hours
            # reachable: the calibration's statistic rose above its floor at least half as
            # often as asked, and the judged hours hold at least one alarm at half the rate
            resolvable = threshold.measured_per_hour >= rate / 2 and rate / 2 * hours >= 1
            ok = rate / 2 <= measured <= 2 * rate
            reachable += resolvable
            within += resolvable and ok
            mark = ("yes" if ok else "no") if resolvable else "unreachable"
            print(
                f"{detector:18s} {rate:8g} {threshold.log_lr:10.2f} {measured:10.2f}  "
                f"[{lo:.2f}, {hi:.2f}]  within x2: {mark}"
            )
    print(f"\ncells within x2 of the rate asked: {within} of {reachable} reachable")


if __name__ == "__main__":
    main()
