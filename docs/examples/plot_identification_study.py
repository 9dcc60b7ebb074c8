"""
Paper A's identification study on a simulated wheel
===================================================

A 20-minute PRBS is played into the simulated RW90 over a virtual CAN bus and
recorded (``.mcap``); paper A's study chooses a model (delay scan, ARX orders,
ARMAX/OE/BJ, validation), and ``model.json`` is written by its one owner,
:class:`rwlab.ident.model_file.WheelModelFile`.
"""

import tempfile
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np

from rwlab.ident.study import identification_study, load_study_data, wheel_model
from rwlab.testbed import ExperimentConfig, run_experiment
from rwlab.wheel import IdentifiedWheel

work = Path(tempfile.mkdtemp())
summary = run_experiment(ExperimentConfig(duration=1200, Ts=0.5, seed=5), work / "prbs.mcap")
print(summary)

data, saturation = load_study_data(str(work / "prbs.mcap"))
result = identification_study(data, nonlinear=False)
print(result.chosen_name, "—", result.reason)

# %%
# The order table: validation fit against the number of parameters.
rows = result.rows
fig, ax = plt.subplots(figsize=(8, 3), constrained_layout=True)
ax.plot([r["n_params"] for r in rows], [r["fit_percent"] for r in rows], "o")
for r in rows:
    ax.annotate(r["structure"], (r["n_params"], r["fit_percent"]), fontsize=7)
ax.set_xlabel("parameters")
ax.set_ylabel("validation fit [%]")

# %%
# The model file, read back as the simulated wheel the attitude loop flies.
path = wheel_model(
    result,
    speed_limit_rpm=saturation["speed_limit_rpm"],
    accel_limit_rpm_s=saturation["accel_limit_rpm_s"],
    saturation_source=saturation["saturation_source"],
).save(work / "model.json")
wheel = IdentifiedWheel.from_json(path)
step = wheel.simulate(np.full(80, 3000.0))
fig, ax = plt.subplots(figsize=(8, 3), constrained_layout=True)
ax.plot(np.arange(step.size) * wheel.Ts, step)
ax.set_xlabel("time [s]")
ax.set_ylabel("speed [rpm]")
ax.set_title("identified wheel: 3000 rpm step (acceleration limit active)")

plt.show()
