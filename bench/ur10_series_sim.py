"""A simulated UR10 laser-tracker series in the format of Landgraf et al.'s (``fgcal import landgraf``).

Independent of fgcal: plain standard-DH 4x4 matrices (numpy only), the UR10's published link
masses and centres of mass, gravity torques by central differences of the potential energy.
The arm reaches each goal with joint errors that no geometric model explains:

- torsional compliance of the shoulder and elbow (11 urad/Nm, as fgcal's compliance+map fit
  finds on the real Series B; 3 urad/Nm on wrist 1) times the gravity torque of the joint;
- a joint error map: for each joint a sum of harmonics ``a_h sin(h q + p_h)`` with amplitudes
  of ~60 urad falling off as 1/sqrt(h) up to the 30th harmonic, random phases (on 1,500 poses
  fgcal's models then fit it as on Series B: held-out 0.47 mm geometric, 0.09 mm compliance,
  0.04 mm compliance+map);

and the tracker measures the probe's pose with Series B's noise (0.011 mm per axis, 0.0023 deg)
plus 0.02 mm per axis of error no model explains. The joint configurations are uniform in Series B's
joint box, each goal visited twice (as Series B's 757 goals are in 1,495 rows), in time order.

Run: ``python bench/ur10_series_sim.py OUT.csv --poses 8400 --seed 0``.
"""
from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

# UR10 standard DH (mm, rad) and the published link masses (kg) and centres of mass (mm, link frames).
D = np.array([127.3, 0.0, 0.0, 163.941, 115.7, 92.2])
A = np.array([0.0, -612.0, -572.3, 0.0, 0.0, 0.0])
ALPHA = np.radians([90.0, 0.0, 0.0, 90.0, -90.0, 0.0])
MASS = np.array([7.1, 12.7, 4.27, 2.0, 2.0, 0.365])
COM = np.array([[21.0, 0, 27.0], [380.0, 0, 158.0], [240.0, 0, 68.0], [0, 7.0, 18.0], [0, 7.0, 18.0], [0, 0, -26.0]])
GRAVITY = np.array([0.0, 0.0, -9.81])  # m/s^2 in the robot's base frame
# Series B's joint box (deg) and noise
Q_LOW = np.radians([-180.0, -138.0, -125.0, -244.0, -145.0, -61.0])
Q_HIGH = np.radians([-45.0, 4.0, 125.0, 3.0, 5.0, 61.0])
SIGMA_POS, SIGMA_ROT_DEG, SIGMA_UNMODELLED = 0.011154, 0.0023175, 0.02
COMPLIANCE = np.array([0.0, 11e-6, 11e-6, 3e-6, 0.0, 0.0])  # rad/Nm
HARMONICS, MAP_AMPLITUDE = 30, 60e-6  # rad


def _rz(a):
    c, s = np.cos(a), np.sin(a)
    T = np.zeros(np.shape(a) + (4, 4))
    T[..., 0, 0], T[..., 0, 1], T[..., 1, 0], T[..., 1, 1] = c, -s, s, c
    T[..., 2, 2] = T[..., 3, 3] = 1.0
    return T


def _rx(a):
    c, s = np.cos(a), np.sin(a)
    T = np.zeros(np.shape(a) + (4, 4))
    T[..., 1, 1], T[..., 1, 2], T[..., 2, 1], T[..., 2, 2] = c, -s, s, c
    T[..., 0, 0] = T[..., 3, 3] = 1.0
    return T


def _ry(a):
    c, s = np.cos(a), np.sin(a)
    T = np.zeros(np.shape(a) + (4, 4))
    T[..., 0, 0], T[..., 0, 2], T[..., 2, 0], T[..., 2, 2] = c, s, -s, c
    T[..., 1, 1] = T[..., 3, 3] = 1.0
    return T


def _trans(x, y, z):
    T = np.eye(4)
    T[:3, 3] = [x, y, z]
    return T


def link_frames(q, d=D, a=A, alpha=ALPHA, theta0=None):
    """(N, 6, 4, 4) frames of links 1..6 in the base frame: A_i = Rz(q+theta0) Tz(d) Tx(a) Rx(alpha)."""
    q = np.atleast_2d(q)
    theta0 = np.zeros(6) if theta0 is None else theta0
    T = np.broadcast_to(np.eye(4), (len(q), 4, 4)).copy()
    out = np.empty((len(q), 6, 4, 4))
    for i in range(6):
        Ai = _rz(q[:, i] + theta0[i]) @ _trans(0, 0, d[i]) @ _trans(a[i], 0, 0) @ _rx(np.full(len(q), alpha[i]))
        T = T @ Ai
        out[:, i] = T
    return out


def potential(q) -> np.ndarray:
    """Gravity's potential energy (J) of the links at joints ``q`` (N, 6), nominal geometry."""
    F = link_frames(q)
    c = F[:, :, :3, 3] + np.einsum("nlij,lj->nli", F[:, :, :3, :3], COM)  # mm
    return -np.einsum("l,nli,i->n", MASS, c, GRAVITY) * 1e-3


def gravity_torques(q, h=1e-6) -> np.ndarray:
    """(N, 6) N m: minus the gradient of the potential (central differences)."""
    tau = np.empty_like(q)
    for j in range(6):
        dq = np.zeros(6)
        dq[j] = h
        tau[:, j] = -(potential(q + dq) - potential(q - dq)) / (2 * h)
    return tau


def xyz_intrinsic_euler(R) -> np.ndarray:
    """(N, 3) deg of R = Rx(a) Ry(b) Rz(c)."""
    b = np.arcsin(np.clip(R[:, 0, 2], -1, 1))
    a = np.arctan2(-R[:, 1, 2], R[:, 2, 2])
    c = np.arctan2(-R[:, 0, 1], R[:, 0, 0])
    return np.degrees(np.stack([a, b, c], axis=1))


def simulate(n_poses: int, rng: np.random.Generator) -> dict:
    """The series' columns: ``q`` (N, 6) rad readings, ``xyz`` (N, 3) mm, ``rpy`` (N, 3) deg, ``goal`` (N,)."""
    n_goals = (n_poses + 1) // 2
    q_goal = rng.uniform(Q_LOW, Q_HIGH, (n_goals, 6))
    goal = np.repeat(np.arange(n_goals), 2)[:n_poses]
    q = q_goal[goal]
    # the true geometry: the nominal plus deviations of a real arm's size
    d = D + rng.normal(0, 0.3, 6)
    a = A + rng.normal(0, 0.3, 6)
    alpha = ALPHA + np.radians(rng.normal(0, 0.02, 6))
    theta0 = np.radians(rng.normal(0, 0.02, 6))
    # joint errors: compliance under gravity, and the map
    amp = MAP_AMPLITUDE * rng.uniform(0.5, 1.5, (6, HARMONICS)) / np.sqrt(np.arange(1, HARMONICS + 1))
    phase = rng.uniform(0, 2 * np.pi, (6, HARMONICS))
    h = np.arange(1, HARMONICS + 1)
    dq = gravity_torques(q) * COMPLIANCE + np.einsum("jh,njh->nj", amp, np.sin(q[:, :, None] * h + phase))
    F = link_frames(q + dq, d, a, alpha, theta0)[:, 5]
    base = _rz(np.radians(20.0)) @ _trans(-748.0, -3525.6, -1096.6)
    tool = _rz(np.radians(-90.0)) @ _trans(0.16, 0.19, 93.1)
    T = base @ F @ tool
    xyz = T[:, :3, 3] + rng.normal(0, SIGMA_POS, (n_poses, 3)) + rng.normal(0, SIGMA_UNMODELLED, (n_poses, 3))
    small = np.radians(rng.normal(0, SIGMA_ROT_DEG, (n_poses, 3)))
    R = T[:, :3, :3] @ (_rx(small[:, 0]) @ _ry(small[:, 1]) @ _rz(small[:, 2]))[:, :3, :3]
    return {"q": q, "xyz": xyz, "rpy": xyz_intrinsic_euler(R), "goal": goal, "goal_q": q_goal}


HEADER = ("Timestamp;Goal x;Goal y;Goal z;Goal roll;Goal pitch;Goal yaw;shoulder_pan_joint;shoulder_lift_joint;"
          "elbow_joint;wrist_1_joint;wrist_2_joint;wrist_3_joint;measurement_temperature;measurement_x;"
          "measurement_std_x;measurement_y;measurement_std_y;measurement_z;measurement_std_z;measurement_rx;"
          "measurement_std_rx;measurement_ry;measurement_std_ry;measurement_rz;measurement_std_rz")


def write_series(path: Path, sim: dict) -> None:
    """The Landgraf CSV (semicolons, decimal commas); the goal columns name each goal."""
    n = len(sim["q"])
    rows = [HEADER]
    for k in range(n):
        g = sim["goal_q"][sim["goal"][k]]
        vals = [20201100000000.0 + k] + list(g) + list(sim["q"][k]) + [21.9]
        for i in range(3):
            vals += [sim["xyz"][k, i], SIGMA_POS]
        for i in range(3):
            vals += [sim["rpy"][k, i], SIGMA_ROT_DEG]
        rows.append(";".join(f"{v:.10g}".replace(".", ",") for v in vals))
    tmp = path.with_suffix(path.suffix + ".tmp")
    tmp.write_text("\n".join(rows) + "\n")
    tmp.replace(path)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out", type=Path)
    ap.add_argument("--poses", type=int, default=8400)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    write_series(args.out, simulate(args.poses, np.random.default_rng(args.seed)))
    print(f"wrote {args.out}: {args.poses} poses")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
