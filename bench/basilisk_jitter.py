"""rwlab's wheel jitter against Basilisk's own JitterSimple on one wheel (issue 44).

The case of tests/test_attitude_jitter.py's first test: geo-smallsat's rigid hub, nothing
acting on it but one wheel (x axis, 300 rad/s relative to the body, U_s = 4.8e-6 kg·m,
U_d = 1.54e-6 kg·m² at r = (0.5, 0.2, -0.3) m), no motor torque, RK4 at 2.5e-4 s. rwlab
flies it through its attitude loop (truth estimator, a controller of gain ~0); Basilisk
(PyPI ``bsk``, in its own venv: it is no rwlab dependency) flies the same hub with a
``reactionWheelStateEffector`` wheel (RWModel = JitterSimple) given rwlab's transverse
axes as w2Hat0_B / w3Hat0_B and θ₀ = 0. Compared every step: the hub's inertial body
rate ω_BN (rwlab logs ω_bo = ω_BN − A(q) (0, −n, 0), relative to the orbital frame) and
the wheel's speed relative to the body.

    PYTHONPATH=src python bench/basilisk_jitter.py --bsk-python /tmp/bskenv/bin/python

runs both (this interpreter: rwlab; ``--bsk-python``: ``--basilisk`` mode, which reads
the case as JSON and never imports rwlab).
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import tempfile
from pathlib import Path

import numpy as np

U_S, U_D = 4.8e-6, 1.54e-6  # kg·m, kg·m² (Basilisk's HR16 values, as the test)
R_WHEEL = (0.5, 0.2, -0.3)  # m, from the centre of mass
OMEGA = 300.0  # rad/s, the wheel relative to the body
DT = 2.5e-4  # s
HUB_MASS = 100.0  # kg; rwlab has no mass: Basilisk's rotation does not depend on it here


def run_basilisk(case: dict) -> dict:
    """Basilisk's hub + one JitterSimple wheel; its log every step (lists, SI units)."""
    from Basilisk.architecture import messaging
    from Basilisk.simulation import reactionWheelStateEffector, spacecraft, svIntegrators
    from Basilisk.utilities import SimulationBaseClass, macros

    sim = SimulationBaseClass.SimBaseClass()
    step_ns = macros.sec2nano(case["dt"])
    sim.CreateNewProcess("proc").addTask(sim.CreateNewTask("task", step_ns))
    sc = spacecraft.Spacecraft()
    sc.hub.mHub = case["mass"]
    sc.hub.r_BcB_B = [[0.0], [0.0], [0.0]]
    sc.hub.IHubPntBc_B = case["inertia"]
    sc.hub.sigma_BNInit = [[0.0], [0.0], [0.0]]
    sc.hub.omega_BN_BInit = [[w] for w in case["omega_BN_B"]]
    sc.setIntegrator(svIntegrators.svIntegratorRK4(sc))

    rw = reactionWheelStateEffector.RWConfigPayload()
    rw.RWModel = messaging.JitterSimple
    rw.gsHat_B = [[g] for g in case["gsHat"]]
    rw.w2Hat0_B = [[a] for a in case["w2Hat0"]]
    rw.w3Hat0_B = [[a] for a in case["w3Hat0"]]
    rw.rWB_B = [[a] for a in case["r"]]
    rw.Js = case["Js"]
    rw.U_s, rw.U_d = case["U_s"], case["U_d"]
    rw.Omega, rw.theta = case["Omega"], 0.0
    rw.u_max = -1.0  # no torque limit (and no command: the motor input stays unlinked)
    wheels = reactionWheelStateEffector.ReactionWheelStateEffector()
    wheels.ModelTag = "wheel"
    wheels.addReactionWheel(rw)
    sc.addStateEffector(wheels)
    sim.AddModelToTask("task", wheels, 2)
    sim.AddModelToTask("task", sc, 1)

    hub_log = sc.scStateOutMsg.recorder()
    rw_log = wheels.rwSpeedOutMsg.recorder()
    sim.AddModelToTask("task", hub_log)
    sim.AddModelToTask("task", rw_log)
    sim.InitializeSimulation()
    sim.ConfigureStopTime(macros.sec2nano(case["duration"]))
    sim.ExecuteSimulation()
    import Basilisk

    return {
        "bsk": getattr(Basilisk, "__version__", "?"),
        "t": (hub_log.times() * macros.NANO2SEC).tolist(),
        "omega_BN_B": np.asarray(hub_log.omega_BN_B).tolist(),
        "sigma_BN": np.asarray(hub_log.sigma_BN).tolist(),
        "Omega": np.asarray(rw_log.wheelSpeeds)[:, 0].tolist(),
        "theta": np.asarray(rw_log.wheelThetas)[:, 0].tolist(),
    }


def run_rwlab(duration: float) -> tuple[dict, dict]:
    """rwlab's loop on the case; returns (the case for Basilisk, rwlab's log)."""
    from rwlab.attitude.frames import GEO_RATE, dcm
    from rwlab.attitude.plant import DisturbanceModel
    from rwlab.attitude.scenario import SCENARIOS
    from rwlab.attitude.sim import PDController, simulate
    from rwlab.attitude.wheels import transverse_axes

    quiet = DisturbanceModel(
        gravity_gradient=False, oblateness=False, solar_pressure=False, third_body=False
    )
    sc = SCENARIOS["geo-smallsat"].with_(
        **{
            "run.dt": DT,
            "run.initial_error_deg": 0.0,
            "sensors.period": DT,  # the log takes every step
            "spacecraft.disturbances": quiet,
            "spacecraft.process_noise_torque": 0.0,
            "wheels.static_imbalance_kg_m": (U_S, 0.0, 0.0),
            "wheels.dynamic_imbalance_kg_m2": (U_D, 0.0, 0.0),
            "wheels.positions_m": (R_WHEEL, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0)),
            "wheels.jitter": True,
        }
    )
    js, g = sc.wheels.inertia, sc.wheel_matrix[:, 0]
    # the loop needs an invertible rate gain: 1e-30 N·m·s/rad adds < 1e-34 N·m
    ctl = PDController(0.0, 1e-30)
    run = simulate(
        sc, ctl, estimator="truth", duration=duration, seed=0, log_every=1, steady_after=0.0,
        wheel_momentum0=np.array([js * OMEGA, 0.0, 0.0]),
    )  # fmt: skip
    # ω_bo = ω_BN − A(q) (0, −n, 0): the inertial rate is ω_bo plus the orbital frame's
    w = run.w_bo + np.array([dcm(q) @ np.array([0.0, -GEO_RATE, 0.0]) for q in run.q])
    omega = run.wheel_speed_rpm[:, 0] * math.pi / 30 - w @ g  # absolute → relative
    axes = transverse_axes(sc.wheel_matrix)[0]
    case = {
        # rwlab's J leaves out the wheel's spin inertia; Basilisk's hub holds it (plant.py)
        "inertia": (sc.inertia_matrix + js * np.outer(g, g)).tolist(),
        "mass": HUB_MASS,
        "omega_BN_B": w[0].tolist(),
        "gsHat": g.tolist(),
        "w2Hat0": axes[0].tolist(),
        "w3Hat0": axes[1].tolist(),
        "r": list(R_WHEEL),
        "Js": js,
        "U_s": U_S,
        "U_d": U_D,
        "Omega": float(omega[0]),
        "dt": DT,
        "duration": duration,
    }
    log = {"t": run.t, "omega_BN_B": w, "Omega": omega, "torque": run.torque}
    return case, log


def amplitudes(case: dict) -> str:
    """The jitter torque's size at the case's speed: U_d Ω² and |r × U_s Ω² ŵ₂(θ)| over a turn."""
    theta = np.linspace(0.0, 2 * math.pi, 721)[:, None]
    w2 = np.cos(theta) * case["w2Hat0"] + np.sin(theta) * case["w3Hat0"]
    omega2 = case["Omega"] ** 2
    lever = np.linalg.norm(np.cross(case["r"], case["U_s"] * omega2 * w2), axis=1)
    return (
        f"U_d Ω² = {case['U_d'] * omega2:.4f} N·m, "
        f"|r × U_s Ω² ŵ₂(θ)| = {lever.min():.4f} … {lever.max():.4f} N·m"
    )


def compare(case: dict, ours: dict, bsk: dict) -> None:
    """Print the per-axis table for one duration."""
    t_b, w_b = np.asarray(bsk["t"]), np.asarray(bsk["omega_BN_B"])
    assert np.allclose(t_b, ours["t"], atol=1e-9), "the two logs' times differ"
    w = ours["omega_BN_B"]
    print(f"\n{case['duration']:g} s ({len(t_b) - 1} steps of {case['dt']:g} s), bsk {bsk['bsk']}")
    print(f"  Ω = {case['Omega']:g} rad/s: {amplitudes(case)}")
    print(f"  initial ω_BN_B (both) = {np.array2string(w[0], precision=4)} rad/s")
    print(f"  {'axis':>4} {'swing rad/s':>12} {'max |Δω| rad/s':>15} {'Δ/swing':>9}")
    for i, name in enumerate("xyz"):
        swing = np.ptp(w_b[:, i])
        diff = np.abs(w[:, i] - w_b[:, i]).max()
        print(f"  {name:>4} {swing:12.4e} {diff:15.3e} {diff / swing:9.2e}")
    d_omega = np.abs(ours["Omega"] - np.asarray(bsk["Omega"])).max()
    theta = np.unwrap(bsk["theta"])
    turns = (theta[-1] - theta[0]) / (2 * math.pi)
    print(f"  wheel Ω: max |Δ| = {d_omega:.2e} rad/s; Basilisk's θ turned {turns:.3f} turns")
    print(f"  rwlab's control torque: max |τ| = {np.abs(ours['torque']).max():.1e} N·m")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--basilisk", action="store_true", help="run Basilisk's part (bsk's python)")
    ap.add_argument("--case", help="--basilisk: the case as JSON (file)")
    ap.add_argument("--out", help="--basilisk: where its log goes (JSON)")
    ap.add_argument("--bsk-python", default="/tmp/bskenv/bin/python")
    ap.add_argument("--duration", type=float, nargs="+", default=[0.03, 0.2], help="s")
    args = ap.parse_args()
    if args.basilisk:
        Path(args.out).write_text(json.dumps(run_basilisk(json.loads(Path(args.case).read_text()))))
        return
    with tempfile.TemporaryDirectory() as tmp:
        for duration in args.duration:
            case, ours = run_rwlab(duration)
            case_file, out_file = Path(tmp, "case.json"), Path(tmp, "bsk.json")
            case_file.write_text(json.dumps(case))
            cmd = [args.bsk_python, __file__, "--basilisk", "--case", str(case_file)]
            subprocess.run([*cmd, "--out", str(out_file)], check=True)
            compare(case, ours, json.loads(out_file.read_text()))


if __name__ == "__main__":
    main()
