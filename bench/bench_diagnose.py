"""False-alarm rates, detection and naming of ``rwlab diagnose`` on units it was not tuned on.

Run:  python bench/bench_diagnose.py [--set eval] [--part all] [--cache DIR]
      [--rates 1 10 100] [--model-unit 0 [N ...| nominal | path/model.json]]

A model (with its healthy reference) is identified by ``rwlab identify``, with
the defaults (paper A's stepped PRBS), on a fault-free 20-minute record of unit
0 of the realistic twin (``ExperimentConfig.unit``), or of each ``--model-unit``
(the user identifies on one unit and diagnoses others: every model is judged on
its own, then the tables are pooled over the models; a model file is taken as it
is). Every other record comes from other units, in disjoint sets:

- ``tune``: healthy units 1–6 (2 h) and the calibration's 101–136 (12 h) and
  2000–2077 (26 h), faulty units 41–63: what the detectors were developed on;
- ``eval``: healthy units 21–44 (8 h), faulty units 61–85: judged only (it
  has been looked at while the detectors were developed);
- ``eval2``: healthy units 201–224 (8 h), faulty units 231–255, the eval set's
  faults and signals on fresh units and seeds: run once, after all tuning (then
  seen while the lag fix and the rest-reading test were made);
- ``eval3``: healthy units 601–624 (8 h), faulty units 631–655, the same on
  fresh units and seeds again: run once, after the rest-reading test;
- ``eval4``: healthy units 1300–1395 (32 h), faulty units 1401–1434, the same
  again on fresh units and seeds, with four times eval3's healthy units: a
  detector whose false alarms come from the few units at the edge of the
  spread (the motor test's, from units of high I/k_t) needs that many units for
  its rate to mean something. Run once, after the calibration's 2000s were
  added, with models of fresh units (1500–1599);
- ``eval5``: healthy units 1600–1695 (32 h), faulty units 1701–1734, the same
  once more: eval4's default-rate false alarms (a repeating motion's rest
  readings, a friction-change law extrapolated to unseen speeds) were fixed on
  its records, so the fixes are judged here, with models of units 1800–1899;
- ``eval6``: healthy units 2200–2295 (32 h), faulty units 2301–2334, once more:
  eval5's three default-rate false alarms (the friction-change law's prior
  outweighing its own baseline) were fixed on its records, so that fix is judged
  here, with models of units 2400–2499;
- ``eval7``: healthy units 3000–3095 (32 h), faulty units 3101–3134, once more
  after the slew_change test (friction on a chirp, against the record's own
  slews) and the grey box's breakaway rule, with models of units 3200–3299.

1. false alarms: the healthy 20-minute records (PRBS, chirp, multisine, steps
   in turn) diagnosed at the default rate (latched) and with restarting
   detectors (``latch=False``) at each requested rate; the table prints
   requested vs measured per detector and the hours behind each figure;
2. faults: each fault of issue 23 (two at once too), onset at 600 s of a
   15-minute PRBS and chirp, and present from power-up (t = 0, 10-minute PRBS);
   in the eval set also friction and bias at 300 s of a chirp (its slow part);
   in every set, on units after the set's others (tune 59–63, eval 86–90, eval2
   256–260, eval3 656–660), the review's cases: friction on a multisine and on
   steps, friction + current limit (PRBS), bias + current limit (multisine),
   friction + bias (steps):
   any alarm before onset, detected within 300 s of onset (any time when
   present from t = 0), named right (the first name is the fault's and no
   other fault is named within the 300 s; two faults: both named and no
   third), the sizes; a confusion matrix.

Records are cached in ``--cache`` (same names, same records), so a change of
the detector can be re-judged without re-simulating. Simulated clock; a
20-minute record takes ~10–30 s. A benchmark, not a test.
"""

from __future__ import annotations

import argparse
import math
import tempfile
import warnings
from collections import Counter, defaultdict
from pathlib import Path

import numpy as np
from click.testing import CliRunner
from scipy.stats import chi2

from rwlab.cli import main as cli
from rwlab.diagnose import HealthyReference, diagnose
from rwlab.diagnose.diagnosis import RECORD_OUTPUTS
from rwlab.errors import RwlabWarning
from rwlab.testbed import ExperimentConfig, load_record, run_experiment
from rwlab.wheel import IdentifiedWheel

SIGNALS = ("prbs", "chirp", "multisine", "step")
DETECTORS = (
    "rest",
    "offset",
    "slew",
    "slew_change",
    "friction",
    "friction_change",
    "hold",
    "motor",
    "speed",
    "lag",
    "clamped",
    "charge",
    "stuck",
    "dropout",
)
FIXED = ("rest", "clamped", "charge")  # a fixed limit, no false-alarm rate to set
ONSET = 600.0
FAULTS = {
    "tune": (
        "friction=1.5",
        "torque_constant=0.8",
        "speed_sensor_bias=15",
        "current_limit=0.45",
        "speed_sensor_stuck",
        "telemetry_dropout=0.3",
        "friction=1.5+speed_sensor_bias=15",
        "torque_constant=0.8+speed_sensor_bias=20",
    ),
    "eval": (
        "friction=1.5",
        "torque_constant=0.8",
        "speed_sensor_bias=10",
        "speed_sensor_bias=20",
        "current_limit=0.45",
        "speed_sensor_stuck",
        "telemetry_dropout=0.3",
        "friction=1.5+speed_sensor_bias=15",
        "torque_constant=0.8+speed_sensor_bias=20",
    ),
}
FAULTS.update(
    {name: FAULTS["eval"] for name in ("eval2", "eval3", "eval4", "eval5", "eval6", "eval7")}
)
POWER_UP = (
    "friction=1.5",
    "torque_constant=0.8",
    "speed_sensor_bias=15",
    "current_limit=0.45",
    "speed_sensor_stuck",
)
EARLY_CHIRP = ("friction=1.5", "speed_sensor_bias=15")
# issue 23's review (units 300–363): friction on the signals with no through-zero slew at
# the limit, and the pairs that were named as one fault; onset at 600 s of 15 minutes
MORE = (
    ("friction=1.5", "multisine"),
    ("friction=1.5", "step"),
    ("friction=1.5+current_limit=0.45", "prbs"),
    ("speed_sensor_bias=15+current_limit=0.45", "multisine"),
    ("friction=1.5+speed_sensor_bias=15", "step"),
    # the held-out 700s (units 769, 791): a weak motor on a chirp named friction too; a weak
    # motor with a frozen reading, which the diagnosis must say it could not see
    ("torque_constant=0.9", "chirp"),
    ("torque_constant=0.8+speed_sensor_stuck", "step"),
    # the held-out 800s (unit 865): a bias with a clamp on a chirp, named late by the rest test
    ("speed_sensor_bias=15+current_limit=0.45", "chirp"),
)
HEALTHY = {
    "tune": (1, 6, 100),
    "eval": (21, 24, 1000),
    "eval2": (201, 24, 7000),
    "eval3": (601, 24, 11000),
    "eval4": (1300, 96, 13000),
    "eval5": (1600, 96, 15000),
    "eval6": (2200, 96, 17000),
    "eval7": (3000, 96, 19000),
}
# (first unit, records, first seed, name): more healthy tune records, the thresholds' data.
# The 2000s were added when the motor test's rates on eval3 (0.16/h for 1 asked) showed
# that 42 units hold too few of the spread's edge: 12 % of the tune units have I/k_t ≥
# 1.045 × nominal, 0 % of eval3's, 8 % of the population's
CALIBRATION = ((101, 36, 3000, "x"), (2000, 78, 52000, "y"))
FIRST_FAULTY_UNIT = dict(
    tune=41,
    eval=61,
    eval2=231,
    eval3=631,
    eval4=1401,
    eval5=1701,
    eval6=2301,
    eval7=3101,
)
FAULT_SEED = dict(
    tune=200, eval=2000, eval2=8000, eval3=12000, eval4=14000, eval5=16000, eval6=18000, eval7=20000
)


def _faults(text: str, onset: float) -> tuple[str, ...]:
    """'a=1+b=2' → ('a=1@600', 'b=2@600') (dropouts: five, 60 s apart)."""
    out: list[str] = []
    for part in text.split("+"):
        if part.startswith("telemetry_dropout"):
            out += [f"{part}@{onset + 60 * i:g}" for i in range(5)]
        else:
            out.append(f"{part}@{onset:g}")
    return tuple(out)


def records(which: str) -> dict[str, tuple]:
    """name → (unit, seed, signal, duration s, faults, fault text, onset s) of a set."""
    out: dict[str, tuple] = {}
    first, n, seed = HEALTHY[which]
    for i in range(n):
        out[f"{which}_h{i}"] = (first + i, seed + i, SIGNALS[i % 4], 1200, (), "", None)
    if which == "tune":
        for first, n, seed, tag in CALIBRATION:
            for i in range(n):
                out[f"tune_{tag}{i}"] = (first + i, seed + i, SIGNALS[i % 4], 1200, (), "", None)
    unit = FIRST_FAULTY_UNIT[which] - 1
    for fault in FAULTS[which]:
        for signal in ("prbs", "chirp"):
            unit += 1
            seed = FAULT_SEED[which] + unit
            out[f"{which}_f{unit}"] = (
                unit,
                seed,
                signal,
                900,
                _faults(fault, ONSET),
                fault,
                ONSET,
            )
    seed = FAULT_SEED[which]
    for fault in POWER_UP if which != "tune" else ():
        unit += 1
        spec = (unit, seed + unit, "prbs", 600, _faults(fault, 0), fault, 0.0)
        out[f"{which}_p{unit}"] = spec
    for fault in EARLY_CHIRP:  # onset in the chirp's slow first third
        unit += 1
        spec = (unit, seed + unit, "chirp", 900, _faults(fault, 300), fault, 300.0)
        out[f"{which}_c{unit}"] = spec
    for fault, signal in MORE:
        unit += 1
        spec = (unit, seed + unit, signal, 900, _faults(fault, ONSET), fault, ONSET)
        out[f"{which}_e{unit}"] = spec
    return out


def _record(cache: Path, name: str, spec: tuple) -> Path:
    path = cache / f"{name}.mcap"
    if not path.exists():
        unit, seed, signal, duration, faults, _, _ = spec
        cfg = ExperimentConfig(
            signal=signal, duration=duration, seed=seed, unit=unit, faults=faults
        )
        run_experiment(cfg, cache / "tmp.mcap", force=True)
        (cache / "tmp.mcap").rename(path)
    return path


def load(path: Path, Ts: float):
    """A record as the detectors read it (every output they use, gaps kept)."""
    return load_record(path, Ts, outputs=RECORD_OUTPUTS, max_gap=np.inf)


def healthy_tune(cache: Path, Ts: float) -> list:
    """The tune set's healthy records (the thresholds' data), loaded."""
    specs = {k: v for k, v in records("tune").items() if not v[5]}
    return [load(_record(cache, name, spec), Ts) for name, spec in specs.items()]


def _model(cache: Path, out: Path, unit: str = "0") -> Path:
    """Identified with this code every run (the reference is the detector's); record cached.

    ``unit``: the model's wheel, a unit number (seed = unit; the bench's is 0, seed 0)
    or 'nominal' (no unit, seed 0: ``rwlab experiment --duration 1200`` as the README).
    """
    record = cache / f"model_unit{unit}.mcap"
    if not record.exists():
        number = None if unit == "nominal" else int(unit)
        cfg = ExperimentConfig(duration=1200, seed=number or 0, unit=number)
        run_experiment(cfg, cache / "m.mcap")
        (cache / "m.mcap").rename(record)
    result = CliRunner().invoke(cli, ["identify", str(record), "--out", str(out / "model")])
    assert result.exit_code == 0, result.output
    return out / "model" / "model.json"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--set", choices=sorted(HEALTHY), default="eval")
    parser.add_argument("--part", choices=["all", "healthy", "faults"], default="all")
    parser.add_argument("--rates", type=float, nargs="+", default=[1.0, 10.0, 100.0])
    parser.add_argument("--cache", type=Path, help="folder keeping the records (default: temp)")
    parser.add_argument(
        "--model-unit",
        nargs="+",
        default=["0"],
        help="the models' wheels: unit numbers or 'nominal' (each judged on its own, then "
        "pooled); a model file's path (model.json) is taken as it is",
    )
    args = parser.parse_args()
    warnings.simplefilter("ignore", RwlabWarning)  # the table prints each detector's note
    specs = records(args.set)
    healthy = {k: v for k, v in specs.items() if not v[5]}
    faulty = {k: v for k, v in specs.items() if v[5]}
    pooled_h: list[tuple] = []
    pooled_f: list[dict] = []
    with tempfile.TemporaryDirectory() as tmp:
        cache = args.cache or Path(tmp)
        cache.mkdir(parents=True, exist_ok=True)
        for unit in args.model_unit:
            if unit.endswith(".json"):
                model = Path(unit)
            else:
                model = _model(cache, Path(tmp) / f"u{unit}", unit)
            wheel = IdentifiedWheel.from_json(model)
            ref = HealthyReference.from_model_file(model)

            def run(path, wheel=wheel, ref=ref, **kw):
                return diagnose(load(path, wheel.Ts), wheel, ref, **kw)

            print(f"set {args.set}; model: unit {unit}, 20-min PRBS (defaults)\n")
            if args.part != "faults":
                pooled_h.append(_healthy(args, run, cache, healthy))
            if args.part != "healthy":
                pooled_f.append(_faults_part(run, cache, faulty))
    if len(args.model_unit) > 1:
        print(f"=== pooled over the model units {', '.join(args.model_unit)} ===\n")
        if pooled_h:
            _pooled_healthy(args, pooled_h)
        if pooled_f:
            _print_totals(
                {
                    k: sum((t[k] for t in pooled_f), start=type(pooled_f[0][k])())
                    for k in pooled_f[0]
                }
            )


def _healthy(args, run, cache: Path, specs: dict) -> tuple:
    per_record: dict[float, list[Counter]] = {rate: [] for rate in args.rates}
    notes: dict[float, dict[str, str]] = {rate: {} for rate in args.rates}
    thresholds: dict[float, dict] = {}
    latched, rec_hours = [], []
    for name, spec in specs.items():
        path = _record(cache, name, spec)
        rec_hours.append(spec[3] / 3600)
        latched += [
            f"{name} ({spec[2]}, unit {spec[0]}): {a.kind} at {a.t_s}" for a in run(path).alarms
        ]
        for rate in args.rates:
            result = run(path, false_alarms_per_hour=rate, latch=False)
            per_record[rate].append(Counter(a.detector for a in result.alarms))
            thresholds[rate] = result.thresholds
            for note in result.notes:
                name, text = note.split(": ", 1)
                if text not in notes[rate].get(name, ""):
                    notes[rate][name] = "; ".join(filter(None, (notes[rate].get(name), text)))
    units = sorted(s[0] for s in specs.values())
    print(
        f"healthy: {sum(rec_hours):.2f} h, units {units[0]}–{units[-1]} ({', '.join(SIGNALS)} "
        f"in turn); alarms at the default 1e-3/h: {len(latched)}"
    )
    for line in latched:
        print("  ", line)
    cells = {rate: _cells([per_record[rate]]) for rate in args.rates}
    _rate_table(args.rates, cells, np.array(rec_hours), thresholds, notes)
    return per_record, np.array(rec_hours), len(latched), notes


def _cells(per_model: list[list[Counter]]) -> dict[str, np.ndarray]:
    """Each detector's alarms per model and record, shape (models, records)."""
    return {d: np.array([[c[d] for c in records] for records in per_model]) for d in DETECTORS}


def _pooled_healthy(args, pooled: list[tuple]) -> None:
    rec_hours = pooled[0][1]
    print(
        f"healthy, all models: {len(pooled) * rec_hours.sum():.2f} h (records × models); "
        f"alarms at the default 1e-3/h: {sum(p[2] for p in pooled)}"
    )
    cells = {rate: _cells([p[0][rate] for p in pooled]) for rate in args.rates}
    # a rate is out of a detector's reach when every model's note says so
    notes = {
        rate: {
            d: pooled[0][3][rate][d]
            for d in DETECTORS
            if all(_out_of_reach(p[3][rate].get(d, "")) for p in pooled)
        }
        for rate in args.rates
    }
    _rate_table(args.rates, cells, rec_hours, None, notes)


def _out_of_reach(note: str) -> bool:
    """The detector's note says no threshold delivers the rate."""
    return "cannot deliver" in note or "not within a factor 2 of any" in note


def _rate_table(rates, cells, rec_hours, thresholds, notes) -> None:
    print(
        f"{'detector':<16} {'requested/h':>11} {'threshold':>9} {'measured/h':>10} "
        f"{'95 % interval/h':>15} {'alarms':>6} {'hours':>5} {'ratio':>6}  "
        "within x2 / what the detector says"
    )
    verdicts: Counter = Counter()
    for d in DETECTORS:
        for rate in rates:
            grid = cells[rate][d]
            n = int(grid.sum())
            hours = grid.shape[0] * float(rec_hours.sum())
            ratio = n / hours / rate
            lo, hi = unit_interval(grid, rec_hours)
            ok = "yes" if 0.5 <= ratio <= 2 else "no"
            if ok == "no" and lo <= 2 * rate and hi >= rate / 2:
                ok = "no, within sampling (its 95 % interval reaches ×2)"
            note = notes[rate].get(d, "") if notes else ""
            if ok != "yes" and (d in FIXED or _out_of_reach(note)):
                verdicts["out"] += 1
            else:
                verdicts["yes" if ok == "yes" else "sampling" if "sampling" in ok else "no"] += 1
            h = thresholds[rate].get(d, math.nan) if thresholds else math.nan
            print(
                f"{d:<16} {rate:>11g} {h:>9.3g} "
                f"{n / hours:>10.3g} {f'{lo:.3g}–{hi:.3g}':>15} {n:>6} {hours:>5.2f} "
                f"{ratio:>6.2f}  {ok}{'; ' + note if note else ''}"
            )
    reach = sum(verdicts.values()) - verdicts["out"]
    print(
        f"within x2: {verdicts['yes']} of the {reach} cells within the detectors' reach "
        f"(of the rest, {verdicts['sampling']} within sampling); {verdicts['out']} cells out "
        "of reach (a fixed limit, or no threshold delivers the rate, as the note says)"
    )
    print("(detectors restarted after each alarm; thresholds from src/rwlab/diagnose/")
    print(" thresholds.json, measured on the tune set by bench/calibrate_thresholds.py;")
    print(" the interval: 95 % over units, the records' and the models' units resampled")
    print(" (2000 draws), widened to the alarm count's exact Poisson interval where that is")
    print(" wider: false alarms cluster on a few pairs of units, so units, not hours, set it)\n")


def unit_interval(grid: np.ndarray, rec_hours: np.ndarray, draws: int = 2000) -> tuple:
    """95 % interval of a pooled rate (alarms per hour) over the units behind it.

    ``grid``: alarms per model and record, shape (models, records); ``rec_hours``: each
    record's hours. Models and records are resampled with replacement (a two-way
    bootstrap), then the interval is widened to the count's Poisson interval.
    """
    rng = np.random.default_rng(0)
    m, r = grid.shape
    rates = np.empty(draws)
    for b in range(draws):
        i = rng.integers(0, m, m)
        j = rng.integers(0, r, r)
        rates[b] = grid[np.ix_(i, j)].sum() / (m * rec_hours[j].sum())
    hours = m * float(rec_hours.sum())
    p_lo, p_hi = poisson_interval(int(grid.sum()))
    lo, hi = np.percentile(rates, [2.5, 97.5])
    return min(float(lo), p_lo / hours), max(float(hi), p_hi / hours)


def poisson_interval(n: int) -> tuple[float, float]:
    """Exact (Garwood) 95 % interval of a Poisson mean from one count ``n``."""
    lo = 0.0 if n == 0 else float(chi2.ppf(0.025, 2 * n) / 2)
    return lo, float(chi2.ppf(0.975, 2 * n + 2) / 2)


def _truth(text: str) -> set[str]:
    return {part.split("=")[0] for part in text.split("+")}


SIZED = ("friction", "torque_constant", "speed_sensor_bias", "current_limit")


def _sizes(text: str) -> dict[str, float]:
    """The injected sizes of the faults that come with a 95 % interval."""
    pairs = (part.split("=") for part in text.split("+") if "=" in part)
    return {name: float(value) for name, value in pairs if name in SIZED}


def _faults_part(run, cache: Path, specs: dict) -> dict:
    confusion: dict[str, Counter] = defaultdict(Counter)
    detected = named = early = both = pairs = 0
    covered: Counter = Counter()
    intervals: Counter = Counter()
    print(
        f"{'record':<10} {'unit':>4} {'fault':<40} {'signal':<6} {'det':>6} {'named':>5} "
        f"{'early':>5} sizes"
    )
    for name, (unit, _, signal, duration, _, text, onset) in specs.items():
        alarms = run(_record(cache, name, specs[name])).alarms
        truth = _truth(text)
        end = duration if onset == 0 else onset + 300
        before = [a for a in alarms if a.t_s < onset]
        after = [a for a in alarms if onset <= a.t_s <= end]
        kinds = {a.kind for a in after}
        ok = bool(after) and (
            kinds == truth if len(truth) > 1 else after[0].kind in truth and kinds == truth
        )
        early += bool(before)
        detected += bool(after)
        named += ok
        if len(truth) > 1:
            pairs += 1
            both += truth <= kinds
        for a in after:
            size = _sizes(text).get(a.kind)
            if size is not None and a.ci is not None:
                intervals[a.kind] += 1
                covered[a.kind] += a.ci[0] <= size <= a.ci[1]
        label = f"{text}{'' if onset == ONSET else f' @{onset:g}'}"
        confusion[label][after[0].kind if after else "none"] += 1
        delay = f"{after[0].t_s - onset:.0f}s" if after else "missed"
        sizes = " ".join(
            dict.fromkeys(
                f"{a.kind}:{a.magnitude:.3g}[{a.ci[0]:.3g},{a.ci[1]:.3g}]"
                if a.magnitude is not None and a.ci is not None
                else a.kind
                for a in after
            )
        )
        print(
            f"{name:<10} {unit:>4} {label:<40} {signal:<6} {delay:>6} {ok!s:>5} "
            f"{len(before):>5} {sizes}"
        )
    tally = {
        "n": len(specs),
        "detected": detected,
        "named": named,
        "both": both,
        "pairs": pairs,
        "early": early,
        "covered": covered,
        "intervals": intervals,
        "confusion": Counter({(f, k): v for f, c in confusion.items() for k, v in c.items()}),
    }
    _print_totals(tally)
    return tally


def _print_totals(t: dict) -> None:
    n, detected, named = t["n"], t["detected"], t["named"]
    print(
        f"\ndetected {detected}/{n} ({100 * detected / n:.0f} %); named right {named}/{detected} "
        f"({100 * named / max(detected, 1):.0f} %); both named {t['both']}/{t['pairs']}; "
        f"records with an alarm before onset: {t['early']}"
    )
    covered, intervals = t["covered"], t["intervals"]
    print(
        "95 % intervals holding the injected size: "
        + ", ".join(f"{k} {covered[k]}/{intervals[k]}" for k in SIZED if intervals[k])
        + " (current limit: the unit's true clamp is within ±2 % of the injected value)"
    )
    print("\nconfusion (injected → first name within the window):")
    confusion: dict[str, dict] = defaultdict(dict)
    for (fault, kind), count in t["confusion"].items():
        confusion[fault][kind] = count
    for fault, c in confusion.items():
        print(f"  {fault:<44} {c}")
    print()


if __name__ == "__main__":
    main()
