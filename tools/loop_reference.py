"""Write (or check) the attitude loop's reference trajectories: tests/data/loop_reference.npz.

Run:  PYTHONPATH=src python tools/loop_reference.py --write   (once, on the code the
      reference stands for; ORIGIN.md names the commit)

Cases: every shipped scenario flown by ``attitude simulate`` (PD on the truth, LQG on the
MEKF) for 120 s, ideal and RW-physics wheels, a re-linearising LQR,
and the HIL ``Satellite`` with wheels that report less than they were asked (so the
reported momentum, not the command, drives the plant) and a wheel taken out of the
allocation. The test ``tests/test_attitude_loop.py`` flies them again and compares.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from rwlab.attitude.control import LQRController, fly
from rwlab.attitude.scenario import SCENARIOS

PATH = Path(__file__).resolve().parent.parent / "tests" / "data" / "loop_reference.npz"
FIELDS = ("t", "q", "w_bo", "q_est", "w_est", "torque", "wheel_speed_rpm", "nees", "sigma")

SIM_CASES = {
    "smallsat-pd": ("geo-smallsat", "pd", {}, {}),
    "smallsat-lqg": ("geo-smallsat", "lqg", {}, {}),
    "comsat-lqg-physics": ("geo-comsat", "lqg", {"wheels.model": "physics"}, {}),
    "comsat-lqr-relin": ("geo-comsat", "lqr", {}, {"update_period": 30.0}),
    "gyro-lqg": ("geo-comsat-gyro", "lqg", {}, {}),
    "star-lqg": ("geo-comsat-star", "lqg", {}, {}),
    "pyramid-lqg": ("geo-smallsat-pyramid", "lqg", {}, {}),
}
HIL_CASES = {
    "hil-smallsat-lqg": ("geo-smallsat", {}, None),
    "hil-gyro": ("geo-smallsat", {"sky.epoch": "2027-09-20T22:00:00"}, None),
    "hil-pyramid-drop": ("geo-smallsat-pyramid", {"momentum.bias": 0.0}, 1),
}
DURATION = 120.0


def sim_cases() -> dict[str, np.ndarray]:
    out = {}
    for name, (scenario, ctl, over, kw) in SIM_CASES.items():
        sc = SCENARIOS[scenario].with_(**over)
        run, _ = fly(sc, ctl, duration=DURATION, seed=7, log_every=10, steady_after=30.0, **kw)
        for f in FIELDS:
            out[f"{name}/{f}"] = np.asarray(getattr(run, f), float)
        out[f"{name}/stats"] = np.array([run.stats[k] for k in sorted(run.stats)], float)
    return out


def hil_case(scenario: str, over: dict, drop: int | None):
    """The Satellite flown with wheels that deliver 97 % of the command; wheel ``drop``
    (if any) leaves the allocation after 30 s and delivers nothing."""
    from rwlab.attitude.sensors import GyroModel
    from rwlab.hil.satellite import Satellite

    if "sky.epoch" in over:
        over = over | {"sensors.gyro": GyroModel()}
    sc = SCENARIOS[scenario].with_(**over)
    sat = Satellite(sc, LQRController(sc), duration=DURATION, seed=3, steady_after=30.0)
    while not sat.done:
        if drop is not None and sat.k == 300:
            active = np.ones(sat.nw, bool)
            active[drop] = False
            sat.set_active(active)
        cmd = sat.wheel_torques()
        h = sat.x[7:] + 0.97 * cmd * sc.run.dt
        if drop is not None and sat.k >= 300:
            h[drop] = sat.x[7 + drop]
        sat.advance(h)
    return sat.result()


def hil_cases() -> dict[str, np.ndarray]:
    out = {}
    for name, (scenario, over, drop) in HIL_CASES.items():
        run = hil_case(scenario, over, drop)
        for f in FIELDS:
            out[f"{name}/{f}"] = np.asarray(getattr(run, f), float)
    return out


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--write", action="store_true")
    args = p.parse_args()
    data = sim_cases() | hil_cases()
    if args.write:
        np.savez_compressed(PATH, **data)
        print(f"wrote {PATH} ({len(data)} arrays)")
        return
    ref = np.load(PATH)
    for key in ref.files:
        a, b = ref[key], data[key]
        print(f"{key:<36} max |diff| {np.nanmax(np.abs(a - b)) if a.size else 0.0:.3g}")


if __name__ == "__main__":
    main()
