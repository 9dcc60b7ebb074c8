"""Does the grey-box wheel's breakaway mean the unit's stiction? (round 3)

The default PRBS seldom stops the wheel, so its fit reports breakaway ``unidentified``.
A record that reverses slowly through zero does show the dwell at rest. Here: a
±600 rpm square wave of period 120 s, rate-limited to 20 rpm/s (20 minutes, Ts = 0.5 s)
on twin units with the Stribeck stiction band and without it, then
:func:`rwlab.ident.greybox.greybox_fit` with the RW90 datasheet start values and
current, its breakaway structure term set to 0 (the raw estimate: what that term is
calibrated from). Printed per unit: the unit's Coulomb and breakaway torques, the
estimates, the relative error of the breakaway, and whether the default fit (with the
term) reports it.

    python bench/greybox_breakaway.py --units 3 7 11 --seed 1

A unit without the stiction band has breakaway = Coulomb in its physics: what the fit
reports above that is the dwell the Hall speed and the drive's zero-speed behaviour
leave at rest, which the grey box can only take as stiction.
"""

from __future__ import annotations

import argparse
from dataclasses import replace

import numpy as np

from rwlab.data import IOData
from rwlab.ident.greybox import STRUCTURE_ERROR, Uncertainty, greybox_fit
from rwlab.ident.study import DATASHEET
from rwlab.signals import rate_limit
from rwlab.wheel import RW90
from rwlab.wheel.physics import Mode, WheelParams, WheelPhysics

TS = 0.5


def reversal_record(params: WheelParams, seed: int) -> tuple[IOData, np.ndarray]:
    """±600 rpm square wave (period 120 s) at 20 rpm/s into the twin: speed, current."""
    t = np.arange(0.0, 1200.0, TS)
    command = rate_limit(600.0 * np.sign(np.sin(2 * np.pi * t / 120.0)), 20.0, TS, initial=0.0)
    wheel = WheelPhysics(params, seed)
    speed, current = np.empty(t.size), np.empty(t.size)
    for k, c in enumerate(command):
        speed[k], current[k] = wheel.measured_speed_rpm(), wheel.measured_current()
        wheel.command(Mode.SPEED, c)
        for _ in range(100):
            wheel.step(TS / 100)
    return IOData(command, speed, TS), current


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--units", type=int, nargs="+", default=[3, 7, 11])
    parser.add_argument("--seed", type=int, default=1)
    args = parser.parse_args()
    print(
        f"{'unit':>4} {'stiction':>8} {'τc':>9} {'τbrk':>9} {'τc fit':>9} {'τbrk fit':>9} "
        f"{'rel err':>8} default fit"
    )
    raw = Uncertainty(structure_error={**STRUCTURE_ERROR, "breakaway": 0.0})
    errors = []
    for unit in args.units:
        for stiction in (False, True):
            p = replace(RW90, stiction=stiction, breakaway_friction=4e-4).for_unit(unit)
            truth = p.breakaway_friction if stiction else p.coulomb_friction
            data, current = reversal_record(p, args.seed)
            fit = dict(kp=0.4, ki=0.08, current=current, **DATASHEET)
            m = greybox_fit(data, uncertainty=raw, **fit)
            rel = m.breakaway / truth - 1.0
            errors.append(rel)
            hidden = "breakaway" in greybox_fit(data, **fit).unidentified
            print(
                f"{unit:>4} {stiction!s:>8} {p.coulomb_friction:9.2e} {truth:9.2e} "
                f"{m.coulomb:9.2e} {m.breakaway:9.2e} {rel:+8.2f} "
                f"{'unidentified' if hidden else 'identified'}"
            )
    print(f"RMS relative error of the breakaway: {np.sqrt(np.mean(np.square(errors))):.2f}")


if __name__ == "__main__":
    main()
