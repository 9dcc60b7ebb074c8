"""The metrics of one closed-loop run: pointing, torque, momentum, the sky's outages.

``metrics(run)`` is what ``metrics.json`` holds for each controller flown and
what a Monte Carlo row adds to the dispersed values.
"""

from __future__ import annotations

import math

import numpy as np

from rwlab.attitude.sim import SimResult

__all__ = ["metrics"]


def metrics(r: SimResult, band_deg: float = 0.1) -> dict:
    """Pointing, torque and momentum metrics of one run.

    Maxima and RMS come from every step; the steady window starts at
    ``r.steady_from_s`` (half the run, at most its first hour), and every
    ``steady_*``, ``*_desaturation*`` and ``torque_saturated_fraction`` /
    ``torque_rms_Nm`` figure is over that window ("excluding desaturation" also
    leaves out unloading windows and ``unload_recovery_s`` after each).
    ``max_error_deg`` and ``torque_peak_Nm`` cover the whole run, the initial
    slew included. ``steady_p99_73_error_deg`` (the 3σ-equivalent percentile)
    and settling come from the logged trace.

    Parameters
    ----------
    r : SimResult
        One run.
    band_deg : float
        Settling band on the pointing error, degrees.

    Returns
    -------
    dict
        The metrics (``metrics.json``'s per-controller entries), SI units or named.
    """
    st = r.stats
    steady_n = max(st["steady_steps"], 1)
    outside = np.flatnonzero(r.error_deg > band_deg)
    settled = outside.size == 0 or outside[-1] < len(r.t) - 1
    theta = np.degrees(2 * r.q[:, :3])
    sign0 = np.sign(theta[0])
    overshoot = float(max(0.0, np.max(-sign0 * theta))) if np.any(sign0) else 0.0
    dt = float(np.median(np.diff(r.t))) if len(r.t) > 1 else 0.0
    est = r.est_error_deg[r.t >= r.steady_from_s]
    steady_log = r.error_deg[r.t >= r.steady_from_s]
    return {
        "steps": int(st["steps"]),
        "max_error_deg": st["max_error_deg"],
        "steady_max_error_deg": st["steady_max_error_deg"],
        "steady_rms_error_deg": math.sqrt(st["steady_error_sq_sum"] / steady_n),
        "steady_p99_73_error_deg": float(np.percentile(steady_log, 99.73))
        if steady_log.size
        else 0.0,
        "max_error_deg_excluding_desaturation": st["steady_max_error_excl_desat_deg"],
        "max_error_during_desaturation_deg": st["max_error_in_desat_deg"],
        "settling_time_s": (float(r.t[outside[-1] + 1]) if outside.size else 0.0)
        if settled
        else None,
        "overshoot_deg": overshoot,
        "control_effort_Nms": float(np.sum(np.abs(r.torque)) * dt),
        "torque_saturated_fraction": st["steady_torque_saturated_steps"] / steady_n,
        "torque_peak_Nm": st["torque_peak_Nm"],
        "torque_rms_Nm": math.sqrt(st["steady_torque_sq_sum"] / steady_n),
        "peak_wheel_speed_rpm": float(np.max(np.abs(r.wheel_speed_rpm))),
        "wheel_momentum_peak_fraction": st["momentum_peak_fraction"],
        "wheel_saturated": bool(r.wheel_saturated),
        "desaturation_count": int(st["desaturation_count"]),
        "thruster_impulse_Nms": st["thruster_impulse_Nms"],
        "steady_rms_estimation_error_deg": float(np.sqrt(np.mean(est**2))) if est.size else 0.0,
        **_filter_metrics(r),
        # torque jitter: RMS of the step-to-step change of each wheel's command over √2 (the
        # σ of its white part); power: mean Σ|τ ω| of the wheels (mechanical, W)
        "torque_jitter_rms_Nm": math.sqrt(st.get("steady_torque_jitter_sq_sum", 0.0) / steady_n),
        "wheel_mechanical_power_W": st.get("steady_wheel_power_sum", 0.0) / steady_n,
        # times any wheel's spin changed sign over the whole run (through the friction's
        # breakaway at rest: see ``Scenario.wheel_stiction`` and ``momentum_bias``)
        "wheel_zero_crossings": int(st.get("wheel_zero_crossings", 0)),
        "meets_requirement": bool(st["steady_max_error_deg"] <= band_deg),
        **_sky_metrics(st),
    }


def _filter_metrics(r: SimResult) -> dict:
    """The filter's consistency over the steady window: mean NEES (against the right truth
    for its state: ω, the disturbance state's true value, or the gyro bias), its state
    count, and the share of attitude-error samples inside ±3σ."""
    if r.sigma is None or r.est_error_axes is None or not np.any(r.sigma):
        return {"nees_mean": None, "nees_states": None, "inside_3sigma_fraction": None}
    steady = r.t >= r.steady_from_s
    nees = r.nees[steady]
    nees = nees[np.isfinite(nees)]
    inside = np.abs(r.est_error_axes[steady]) <= 3 * r.sigma[steady, :3]
    return {
        "nees_mean": float(np.mean(nees)) if nees.size else None,
        "nees_states": int(r.stats.get("filter_states", 6)),
        "inside_3sigma_fraction": float(np.mean(inside)) if inside.size else None,
    }


def _sky_metrics(st: dict) -> dict:
    """Eclipse time (the Earth's umbra + penumbra), pointing inside and outside it (steady
    window; None when the window has no step there), and the sensors' outages,
    blindings and gated measurements (sensor ticks)."""
    n_ecl = st["steady_eclipse_steps"]
    n_out = st["steady_steps"] - n_ecl
    period = st.get("sensor_period_s", 0.0)
    return {
        "eclipse_s": st["eclipse_steps"] * st.get("dt_s", 0.0),
        "moon_shadow_s": st["moon_shadow_steps"] * st.get("dt_s", 0.0),
        # null, not 0, for a window with no step in it (no shadow in the steady state)
        "steady_max_error_in_eclipse_deg": st["steady_eclipse_max_error_deg"] if n_ecl else None,
        "steady_rms_error_in_eclipse_deg": (
            math.sqrt(st["steady_eclipse_error_sq_sum"] / n_ecl) if n_ecl else None
        ),
        "steady_max_error_outside_eclipse_deg": (
            st["steady_outside_eclipse_max_error_deg"] if n_out else None
        ),
        "steady_rms_error_outside_eclipse_deg": (
            math.sqrt(st["steady_outside_eclipse_error_sq_sum"] / n_out) if n_out else None
        ),
        "sun_sensor_outage_count": int(st["sun_sensor_outages"]),
        "sun_sensor_outage_s": st["sun_sensor_outages"] * period,
        "earth_sensor_blinded_count": int(st["earth_sensor_blinded"]),
        "earth_sensor_blinded_s": st["earth_sensor_blinded"] * period,
        "no_sensor_s": st["no_update_ticks"] * period,
        "sun_sensor_gated_count": int(st["sun_sensor_gated"]),
        "earth_sensor_gated_count": int(st["earth_sensor_gated"]),
    }
