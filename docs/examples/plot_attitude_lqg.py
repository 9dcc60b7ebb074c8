"""
LQR and LQG on the GEO smallsat
===============================

Paper B's two loops on the built-in smallsat: the LQR flown on the true state,
the LQG on the multiplicative EKF's estimate from the sun and earth sensors.
Ten minutes, one seed; the steady-state pointing error is what the budget
counts.
"""

import matplotlib.pyplot as plt

from rwlab.attitude.control import fly
from rwlab.attitude.scenario import SCENARIOS

sc = SCENARIOS["geo-smallsat"]
runs = {c: fly(sc, c, duration=600.0, seed=1) for c in ("lqr", "lqg")}

fig, ax = plt.subplots(figsize=(8, 3), constrained_layout=True)
for name, (run, metrics) in runs.items():
    ax.semilogy(run.t, run.error_deg, lw=1, label=name)
    print(f"{name}: steady max error {metrics['steady_max_error_deg']:.4f} deg")
ax.axhline(sc.control.pointing_requirement_deg, color="k", ls="--", lw=1, label="requirement")
ax.set_xlabel("time [s]")
ax.set_ylabel("pointing error [deg]")
ax.legend()

plt.show()
