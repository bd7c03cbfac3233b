"""The elimination on each pose's own theta columns (set-up unknowns touched by few poses) gives the
same normal equations, Schur complement, step, covariance and leverage as the dense products, and
those agree with a dense factorisation of the whole problem."""
from __future__ import annotations

import numpy as np
import pytest

import fgcal.estimation.elimination as elimination
from fgcal.estimation.column_groups import active_columns, pose_columns
from fgcal.estimation.elimination import ArrowElimination
from fgcal.estimation.graph_types import Linearisation, State

N, MT, NZ, K, SOCKETS = 120, 3, 6, 21, 30  # poses, theta rows a pose, joints a pose, kinematic params, sockets
P = K + 3 * SOCKETS


class _Arrow(ArrowElimination):
    """The layout of a contact graph: every pose's joints are variables, theta = kinematics + sockets."""

    def __init__(self, lin: Linearisation):
        self.n_poses, self.m, self.nz, self.n_joints = N, MT + NZ, NZ, NZ
        self.n_geo, self.K, self.S = K, 0, 3 * SOCKETS  # theta: the kinematics, then the sockets
        self.local_used = np.ones((N, NZ), dtype=bool)
        self.joint_vars = True
        self.ball_pose = np.zeros(0, dtype=int)
        self.ball_col = np.zeros(0, dtype=int)
        self.row, self.excluded, self.prior = {}, {}, None
        self._lin = lin

    def linearise(self, state):
        return self._lin


def _contact_linearisation(rng) -> Linearisation:
    """Random whitened Jacobians with a contact problem's pattern: each pose's 3 rows touch the
    kinematic columns and its socket's 3; its joint readings add NZ rows on its joints only."""
    socket = rng.permutation(np.arange(N) % SOCKETS)  # every socket seen by N / SOCKETS poses
    J_theta = np.zeros((N, MT, P))
    J_theta[:, :, :K] = rng.normal(size=(N, MT, K))
    J_theta[:, :, K:][np.arange(N)[:, None, None], np.arange(MT)[None, :, None],
                      3 * socket[:, None, None] + np.arange(3)] = rng.normal(size=(N, MT, 3))
    J_theta[5, :, 4] = 0.0  # an exact zero in a kinematic column (a joint at zero): still a common column
    J_local = np.concatenate([rng.normal(size=(N, MT, NZ)), np.broadcast_to(10.0 * np.eye(NZ), (N, NZ, NZ))], axis=1)
    prior_J = np.zeros((3, P))
    prior_J[:, K:K + 3] = np.eye(3)  # a gauge prior on one socket
    return Linearisation(r=rng.normal(size=(N, MT + NZ)), J_stored=J_theta, J_local=J_local,
                         prior_r=rng.normal(size=3), prior_J=prior_J, cost=0.0)


def _everything(lin: Linearisation):
    graph = _Arrow(lin)
    state = State(theta=np.zeros(P), q=np.zeros((N, NZ)), c=np.zeros((0, 3)))
    A, B, D, g_t, g_z = graph.normal_equations(lin)
    S, rhs, _ = graph.reduced(A, B, D, g_t, g_z, damping=1e-3, lin=lin)
    _, d_theta, predicted = graph.step(state, lin, 1e-3)
    cov = graph.covariance(state, lin)
    return {"A": A, "S": S, "rhs": rhs, "d_theta": d_theta, "predicted": np.array(predicted),
            "information": graph.parameter_information(state, lin), "cov": cov,
            "leverage": graph.row_leverage(state, cov, lin)}


def _rel(a, b):
    return float(np.max(np.abs(a - b)) / np.max(np.abs(b)))


def test_pose_columns_list_each_pose_s_own_columns_after_the_common_ones():
    lin = _contact_linearisation(np.random.default_rng(3))
    pc = pose_columns(active_columns(lin.J_theta))
    assert pc is not None and pc.k == K and pc.cols.shape == (N, K + 3)
    assert np.array_equal(pc.cols[:, :K], np.broadcast_to(np.arange(K), (N, K)))
    own = pc.cols[:, K:] - K
    assert np.all(own % 3 == np.arange(3)) and np.all(own[:, 1:] == own[:, :1] + np.arange(1, 3))
    # A dense-only pattern (the point type): no columns, the dense products.
    assert pose_columns(np.ones((N, K), dtype=bool)) is None


@pytest.mark.parametrize("chunk", [elimination.POSE_CHUNK, 50])
def test_pose_column_products_equal_the_dense_ones(monkeypatch, chunk):
    """Also in chunks of poses (50 of 120 here, as a graph of more poses than POSE_CHUNK has them),
    each chunk's index tables kept on the pattern's object."""
    monkeypatch.setattr(elimination, "POSE_CHUNK", chunk)
    lin = _contact_linearisation(np.random.default_rng(7))
    sparse = _everything(lin)
    assert lin.cache["columns"] is not None  # the pose-column path ran
    dense_lin = _contact_linearisation(np.random.default_rng(7))
    monkeypatch.setattr(elimination, "pose_columns", lambda active: None)
    monkeypatch.setattr(elimination.SetupSplit, "of", classmethod(lambda cls, S, g, s: None))
    dense = _everything(dense_lin)
    assert dense_lin.cache["columns"] is None
    for name, value in dense.items():
        assert _rel(sparse[name], value) < 1e-10, name


def test_pose_column_covariance_and_leverage_match_a_dense_factorisation():
    """The step's solve and the covariance by the sockets' blocks (SetupSplit) among them."""
    lin = _contact_linearisation(np.random.default_rng(11))
    out = _everything(lin)
    split = _Arrow(lin)._setup_split(out["information"])
    assert split is not None and [b.shape for b in split.blocks] == [(SOCKETS, 3)]
    # The whole whitened Jacobian: theta columns, then every pose's joints.
    J = np.zeros((N * (MT + NZ) + 3, P + N * NZ))
    for i in range(N):
        rows = slice(i * (MT + NZ), (i + 1) * (MT + NZ))
        J[rows.start:rows.start + MT, :P] = lin.J_theta[i]
        J[rows, P + i * NZ:P + (i + 1) * NZ] = lin.J_local[i]
    J[-3:, :P] = lin.prior_J
    cov_all = np.linalg.inv(J.T @ J)
    assert _rel(out["cov"], cov_all[:P, :P]) < 1e-9
    hat = np.sum((J @ cov_all) * J, axis=1)[:-3].reshape(N, MT + NZ)
    assert _rel(out["leverage"], hat) < 1e-9


def test_dense_products_when_the_pose_columns_save_little():
    active = np.zeros((10, 20), dtype=bool)
    active[:, :16] = True  # 16 common columns and 2 own ones a pose: 18**2 > MIN_SAVING * 20**2
    active[np.arange(10), 16 + np.arange(10) % 2] = True
    active[np.arange(10), 18 + np.arange(10) % 2] = True
    assert pose_columns(active) is None
    active[:, 2:16] = False  # 2 common + 2 own of 20: worth it
    assert pose_columns(active) is not None


def test_without_joint_variables_the_step_and_leverage_match_a_dense_least_squares():
    """Exact readings (no per-pose variables, as the contacts bench): the step is the least squares
    solution of the damped system and the leverage (PoseColumns.hat) is the hat matrix's diagonal."""
    rng = np.random.default_rng(5)
    full = _contact_linearisation(rng)
    lin = Linearisation(r=full.r[:, :MT].copy(), J_stored=full.J_theta, J_local=np.zeros((N, MT, 0)),
                        prior_r=full.prior_r, prior_J=full.prior_J, cost=0.0)
    graph = _Arrow(lin)
    graph.m, graph.nz, graph.joint_vars = MT, 0, False
    graph.local_used = np.zeros((N, 0), dtype=bool)
    state = State(theta=np.zeros(P), q=np.zeros((N, NZ)), c=np.zeros((0, 3)))
    J = np.vstack([lin.J_theta.reshape(-1, P), lin.prior_J])
    r = np.concatenate([lin.r.reshape(-1), lin.prior_r])
    _, d_theta, _ = graph.step(state, lin, 0.0)
    assert lin.cache["columns"] is not None  # the pose-column path ran
    assert _rel(d_theta, -np.linalg.lstsq(J, r, rcond=None)[0]) < 1e-9
    cov = graph.covariance(state, lin)
    hat = np.sum((J @ np.linalg.inv(J.T @ J)) * J, axis=1)[:-3].reshape(N, MT)
    assert _rel(graph.row_leverage(state, cov, lin), hat) < 1e-9
