"""
ARX on the hair dryer, MATLAB's way
===================================

The dryer data set (Ts = 0.08 s): remove the means, split 70/30, find the delay,
estimate ARX(2,2,nk) by least squares and score it on the validation part by
simulation (``compare``) and by the whiteness of its residuals (``resid``).
"""

import matplotlib.pyplot as plt

from rwlab import datasets
from rwlab.ident import arx, compare, delayest, resid

z = datasets.dryer().detrend()
est, val = z.split(0.7)
nk = delayest(est)
m = arx(est, 2, 2, nk)
print(m)

# %%
# Simulation on the validation data, and the residual tests.
c = compare(m, val)
r = resid(m, val)
print(f"delay nk = {nk}; validation fit {c.fit_percent:.1f} %; residuals white: {r.white}")

fig, ax = plt.subplots(figsize=(8, 3), constrained_layout=True)
ax.plot(val.time, c.y[:, 0] if c.y.ndim > 1 else c.y, "k", lw=1, label="measured")
ax.plot(val.time, c.yhat[:, 0] if c.yhat.ndim > 1 else c.yhat, lw=1, label=f"{m.structure}")
ax.set_xlabel("time [s]")
ax.set_ylabel("temperature − mean")
ax.set_title(f"validation: fit {c.fit_percent:.1f} %")
ax.legend()

plt.show()
