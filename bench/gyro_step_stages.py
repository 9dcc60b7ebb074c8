"""Where the gyro LQG step spends its time: each stage alone in a compiled loop.

Run:  python bench/gyro_step_stages.py [--scenario geo-comsat-gyro]

Builds the loop ``attitude simulate`` flies (``sim.Loop``), flies its first hour
(``kernel.run_block``, best of 7 fresh blocks: the compiled step alone, no
Python), and then times each stage of the step in its own numba loop
(compiled without the runtime, as the step is) on copies of the state after
that hour: µs per call, CPU time, best of three. Stages marked "(tick)" run once
per sensor period (every 5 steps at dt 0.1 s, sensors at 0.5 s); the others every
step. The block's set-up (gain, noise draws, sky table) is timed in Python. The
floor is ``minimal_loop``. A benchmark, not a test: numbers depend on the load.
"""

from __future__ import annotations

import argparse
import math
import time

import numpy as np
from numba import njit
from threadpoolctl import threadpool_limits

import minimal_loop
from rwlab.attitude import kernel as K
from rwlab.attitude import sim
from rwlab.attitude.control import LQRController
from rwlab.attitude.ekf import aligned_update_into, gated_update_into
from rwlab.attitude.scenario import SCENARIOS

CLOCK = time.process_time
LEAN = {"_nrt": False, "error_model": "numpy"}
CALLS = 200_000


@njit(**LEAN)
def _command(state, work, plant, law, sky, sensors, filt, noise, calls, tick):
    for i in range(calls):
        j = (i % 1000) * sensors.every + (0 if tick else 1)
        work.flags[K.I_SENSOR] = 0.0
        K.command_step(state, work, 36000 + j, j, plant, law, sky, sensors, filt, noise, 0)


@njit(**LEAN)
def _measure(state, work, sensors, filt, noise, calls):
    for _ in range(calls):
        work.flags[K.I_SENSOR] = 0.0
        K._measure_stage(state, work, sensors, filt, noise.sensor)


@njit(**LEAN)
def _predict(state, work, plant, sensors, filt, calls, tick):
    for _ in range(calls):
        work.flags[K.MEASURED] = 1.0 if tick else 0.0
        K._predict_stage(state, work, plant, sensors, filt)


@njit(**LEAN)
def _propagate(state, work, plant, noise, calls, reported):
    for i in range(calls):
        K._propagate_stage(state, work, plant, noise.process[i % 1000], reported)


@njit(**LEAN)
def _log(state, work, plant, sensors, filt, log, calls):
    for _ in range(calls):
        work.flags[K.MEASURED] = 1.0
        K._log_stage(state, work, plant, sensors, filt, log, 5, 1.0)


@njit(**LEAN)
def _update(state, work, calls, ref, b, aligned):
    P, Pc = state.P, work.F  # each call from the same P (its copy costs ~0.03 µs)
    for _ in range(calls):
        for r in range(P.shape[0]):
            for c in range(P.shape[0]):
                Pc[r, c] = P[r, c]
        if aligned:
            aligned_update_into(state.q_hat, state.w_hat, Pc, b, ref, 1e-3, 0.0, 6, work.Wn)
        else:
            gated_update_into(state.q_hat, state.w_hat, Pc, b, ref, 1e-3, 0.0, work.Wn)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenario", default="geo-comsat-gyro")
    args = parser.parse_args()
    sc = SCENARIOS[args.scenario].with_(**{"wheels.model": "ideal"})
    ctl = LQRController(sc)

    def new_loop() -> sim.Loop:
        return sim.Loop(
            sc,
            ctl,
            steps=36000,
            estimator="ekf",
            log_every=100,
            seed=7,
            wheel_momentum0=None,
            filter_psd=sim.filter_psd(sc, 0.0),
            noise_scale=sc.filter.noise_margin,
            steady_from=0,
        )

    def fly_block(loop: sim.Loop, block) -> None:
        law, sky, noise, n = block
        K.run_block(
            loop.state, loop.work, 0, n, 0, loop.plant, law, sky, loop.sensors, loop.filt,
            noise, loop.wheels, loop.log,
        )  # fmt: skip

    floor = minimal_loop.us_per_step(steps=1_000_000)
    fly_block(new_loop(), new_loop().block(0))  # compile or load outside the timing
    setup = kernel = math.inf
    for _ in range(7):
        loop = new_loop()
        t0 = CLOCK()
        block = loop.block(0)
        setup = min(setup, CLOCK() - t0)
        t0 = CLOCK()
        fly_block(loop, block)
        kernel = min(kernel, CLOCK() - t0)
    n = block[3]
    print(f"{args.scenario}, floor {floor:.4f} µs/step")
    print(f"{'compiled step (run_block, 1 h)':<44} {kernel / n * 1e6:8.4f} µs/step")
    print(f"{'block set-up (gain, noise, sky; Python)':<44} {setup / n * 1e6:8.4f} µs/step")
    law, sky, noise, _ = block
    p, s, f = loop.plant, loop.sensors, loop.filt
    ref, b = np.array([0.0, 0.0, 1.0]), np.array([1e-4, -2e-4, 1.0]) / math.hypot(1, 2.236e-4)
    cases = {
        "command half, no sensor tick": lambda st, w, c: _command(
            st, w, p, law, sky, s, f, noise, c, False
        ),
        "command half (tick)": lambda st, w, c: _command(st, w, p, law, sky, s, f, noise, c, True),
        "  sun + earth updates (tick)": lambda st, w, c: _measure(st, w, s, f, noise, c),
        "  earth update, gated_update_into (tick)": lambda st, w, c: _update(
            st, w, c, ref, b, False
        ),
        "  sun update, aligned_update_into (tick)": lambda st, w, c: _update(
            st, w, c, ref, b, True
        ),
        "log row (every log.every steps)": lambda st, w, c: _log(st, w, p, s, f, loop.log, c),
        "filter prediction, no tick": lambda st, w, c: _predict(st, w, p, s, f, c, False),
        "filter prediction (tick: covariance)": lambda st, w, c: _predict(st, w, p, s, f, c, True),
        "plant RK4 + zero crossings": lambda st, w, c: _propagate(
            st, w, p, noise, c, loop.work.hw_real[:0]
        ),
    }
    if not s.gyro or s.tracker:
        del cases["  sun update, aligned_update_into (tick)"]
    for name, run in cases.items():
        best = math.inf
        for calls in (10, CALLS, CALLS, CALLS):
            state = K.State(*[a.copy() for a in loop.state])
            work = K.Work(*[a.copy() for a in loop.work])
            t0 = CLOCK()
            run(state, work, calls)
            if calls == CALLS:
                best = min(best, CLOCK() - t0)
        print(f"{name:<44} {best / CALLS * 1e6:8.4f} µs/call")


if __name__ == "__main__":
    with threadpool_limits(1, user_api="blas"):
        main()
