"""
State space and frequency response of the dryer
===============================================

``n4sid`` (subspace) and ``ssest`` (prediction error) give second-order
state-space models; their frequency responses are drawn over ``spa``'s
non-parametric estimate with its ±2σ band, an independent check.
"""

import matplotlib.pyplot as plt
import numpy as np

from rwlab import datasets
from rwlab.ident import n4sid, spa, ssest

z = datasets.dryer().detrend()
m1 = n4sid(z, 2)
m2 = ssest(z, 2)
g = spa(z)
print(m2)

w = g.omega
fig, ax = plt.subplots(figsize=(8, 3.5), constrained_layout=True)
mag = np.abs(g.response[:, 0, 0])
ax.loglog(w, mag, "k", lw=1, label="spa")
if g.response_sd is not None:
    sd = g.response_sd[:, 0, 0]
    ax.fill_between(w, np.maximum(mag - 2 * sd, 1e-6), mag + 2 * sd, color="0.85", label="±2σ")
for m, name in ((m1, "n4sid"), (m2, "ssest")):
    ax.loglog(w, np.abs(m.frequency_response(w)[:, 0, 0]), lw=1, label=name)
ax.set_xlabel("ω [rad/s]")
ax.set_ylabel("|G|")
ax.legend()

plt.show()
