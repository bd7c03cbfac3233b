"""The reference for the batch benchmark: a joint probe-level solve written with scipy only.

What a well-informed user would write without fgcal's factor graph: the unknowns are the P
kinematic parameters and a correction ``dq`` (6,) of each pose's joint readings; the ball
centres are eliminated by making each probe point's residual ``|p - FK(theta, q + dq) b| - r``
(``b`` the ball's tool-frame offset, ``r`` its radius), whitened by the CMM sigma, and the joint
corrections have the readings' prior ``dq / sigma_joint``. ``scipy.optimize.least_squares``
(``method="trf"``, ``x_scale="jac"``) solves it with an analytic sparse Jacobian (after a fit of the base placement alone); the
parameters' covariance is the inverse of the Schur complement of the per-pose (6, 6) blocks.

Only the forward kinematics and its Jacobians (``fgcal.robots.kinematics``) and the robot model are
taken from fgcal; the files are read with numpy. Run on a dataset folder:
``python bench/scipy_reference.py DATASET`` prints the estimate and sigmas (file units) as JSON.
"""
from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np


def read_dataset(path):
    """Joint readings (N, 6) deg with their pose ids, probe rows and the dataset's metadata."""
    import yaml

    path = Path(path)
    meta = yaml.safe_load((path / "dataset.yaml").read_text())
    joints = np.loadtxt(path / "joints.csv", delimiter=",", skiprows=1, ndmin=2)
    raw = np.loadtxt(path / "probes.csv", delimiter=",", skiprows=1, dtype=str, ndmin=2)
    probes = (raw[:, 0].astype(int), raw[:, 1], raw[:, 2:5].astype(float))
    return meta, joints[:, 0].astype(int), joints[:, 1:7], probes


def solve(path):
    """``(params, theta (P,), covariance (P, P), result)`` in internal units (mm, rad)."""
    from scipy.optimize import least_squares
    from scipy.sparse import csr_matrix

    from fgcal.robots.kinematics import jacobians
    from fgcal.robots.robot_file import load_model

    meta, pose_ids, q_deg, (p_pose, p_ball, p_xyz) = read_dataset(path)
    model = load_model(meta["robot"])
    params = model.parameters()
    idx = params.index
    P, N = len(idx), len(pose_ids)
    noise = meta.get("noise", {})
    sigma_p = max(float(noise.get("cmm_sigma", 0.01)), 1e-6)
    sigma_q = np.radians(np.hypot(float(noise.get("joint_resolution", 0.01)) / np.sqrt(12.0),
                                  float(noise.get("repeatability", 0.0))))
    radius = float(meta["tool"]["radius"])
    balls = {k: np.asarray(v, dtype=float) for k, v in meta["tool"]["balls"].items()}
    q0 = np.radians(q_deg)

    # Each pose's balls in a padded (N, B, 3) offset array; each probe point indexes (pose, slot).
    row = {int(p): i for i, p in enumerate(pose_ids)}
    pi = np.array([row[int(p)] for p in p_pose])
    keys = list(dict.fromkeys(zip(pi.tolist(), p_ball.tolist())))
    B = max(np.bincount([k[0] for k in keys], minlength=N))
    slot_of, count = {}, np.zeros(N, dtype=int)
    offsets = np.zeros((N, B, 3))
    for i, b in keys:
        slot_of[(i, b)] = count[i]
        offsets[i, count[i]] = balls[b]
        count[i] += 1
    bi = np.array([slot_of[(i, b)] for i, b in zip(pi.tolist(), p_ball.tolist())])
    M = len(pi)

    def unpack(x):
        return x[:P], x[P:].reshape(N, 6)

    def kin(x):
        theta, dq = unpack(x)
        return jacobians(params.full(theta), q0 + dq, offsets)

    cache = {}

    def residuals(x):
        jac = kin(x)
        cache["x"], cache["jac"] = x.copy(), jac
        d = p_xyz - jac.points[pi, bi]
        _, dq = unpack(x)
        return np.concatenate([(np.linalg.norm(d, axis=1) - radius) / sigma_p, dq.ravel() / sigma_q])

    # Sparsity: probe m touches the P parameter columns and its pose's 6 joint columns.
    probe_cols = np.concatenate([np.broadcast_to(np.arange(P), (M, P)), P + 6 * pi[:, None] + np.arange(6)], axis=1)
    indptr = np.concatenate([np.arange(M + 1) * (P + 6), M * (P + 6) + 1 + np.arange(6 * N)])
    indices = np.concatenate([probe_cols.ravel(), P + np.arange(6 * N)])

    def jacobian(x):
        jac = cache["jac"] if "x" in cache and np.array_equal(cache["x"], x) else kin(x)
        d = p_xyz - jac.points[pi, bi]
        u = d / np.linalg.norm(d, axis=1)[:, None]  # d residual / d ball centre = -u
        jt = -np.einsum("mr,mrs->ms", u, jac.point_slots[pi, bi][:, :, idx]) / sigma_p
        jq = -np.einsum("mr,mrj->mj", u, jac.point_joints[pi, bi]) / sigma_p
        data = np.concatenate([np.concatenate([jt, jq], axis=1).ravel(), np.full(6 * N, 1.0 / sigma_q)])
        return csr_matrix((data, indices, indptr), shape=(M + 6 * N, P + 6 * N))

    # Start: the nominal model with its base placement fitted first (6 unknowns, dense): from the
    # nominal base alone the joint solve crawls (LSMR steps on a 7e9 cost).
    base = np.array([n.startswith("base.") for n in params.names])
    theta0 = params.nominal()

    def base_residuals(b):
        th = theta0.copy()
        th[base] = b
        return residuals(np.concatenate([th, np.zeros(6 * N)]))[:M]

    def base_jacobian(b):
        th = theta0.copy()
        th[base] = b
        return jacobian(np.concatenate([th, np.zeros(6 * N)]))[:M, :P][:, np.nonzero(base)[0]].toarray()

    theta0[base] = least_squares(base_residuals, theta0[base], jac=base_jacobian, method="trf", x_scale="jac").x
    x0 = np.concatenate([theta0, np.zeros(6 * N)])
    # LSMR to 1e-12: with its default 1e-6 the inexact steps stop 0.03 sigma short at 10000 poses
    sol = least_squares(residuals, x0, jac=jacobian, method="trf", x_scale="jac",
                        tr_options={"atol": 1e-12, "btol": 1e-12})

    # Covariance: per pose, eliminate the joint block from J^T J (Schur complement on theta).
    J = jacobian(sol.x)
    Jt = J[:, :P].toarray()
    A = Jt.T @ Jt
    jq = J.data[:M * (P + 6)].reshape(M, P + 6)[:, P:]
    order = np.argsort(pi, kind="stable")
    starts = np.searchsorted(pi[order], np.arange(N))
    D = np.add.reduceat(jq[order, :, None] * jq[order, None, :], starts) + np.eye(6) / sigma_q**2
    Bm = np.add.reduceat(Jt[order, :, None] * jq[order, None, :], starts)
    S = A - np.einsum("npz,nzy,nqy->pq", Bm, np.linalg.inv(D), Bm)
    cov = np.linalg.inv(S)
    return params, sol.x[:P], cov, sol


def main():
    params, theta, cov, sol = solve(sys.argv[1])
    scale = np.where(params.is_angle, np.degrees(1.0), 1.0)
    print(json.dumps({"names": list(params.names), "estimate": (theta * scale).tolist(),
                      "sigma": (np.sqrt(np.diag(cov)) * scale).tolist(), "nfev": int(sol.nfev),
                      "cost": float(sol.cost)}))


if __name__ == "__main__":
    main()
