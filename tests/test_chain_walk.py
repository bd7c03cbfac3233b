"""The batch kinematics (fgcal.robots.chain_walk: frame columns mixed by cosines and sines, screws
formed at once) give the numbers of the operation-by-operation walk they replaced
(tests/kinematics_reference.py) to rounding, and the tool pose of an independent plain-matrix DH
(tests/plain_dh.py), for revolute, 7-joint, prismatic and coupled chains with a tool offset."""
from __future__ import annotations

import math

import kinematics_reference as ref
import numpy as np
import pytest
from plain_dh import Rx, Rz, Trans

from fgcal.robots import chain_walk
from fgcal.robots.kinematics import Chain, tool_points

CHAINS = {
    "6R": lambda rng: Chain(("revolute",) * 6),
    "7R": lambda rng: Chain(("revolute",) * 7),
    "prismatic": lambda rng: Chain(("revolute", "revolute", "prismatic", "revolute", "revolute", "revolute")),
    "last_prismatic": lambda rng: Chain(("revolute",) * 3 + ("prismatic",)),
    "coupled_with_tool_offset": lambda rng: Chain(
        ("revolute",) * 6, joint_map=np.eye(6) + 0.3 * np.eye(6, k=1), joint_offset=rng.normal(size=6),
        tool_offset=np.array([[0, -1, 0, 5], [1, 0, 0, 6], [0, 0, 1, 7], [0, 0, 0, 1.0]])),
}


def _case(kind, seed, n_poses=7):
    rng = np.random.default_rng(seed)
    chain = CHAINS[kind](rng)
    x = rng.normal(size=chain.n_slots) * 200
    x[:3] = rng.normal(size=3)
    x[rng.choice(chain.n_slots, 4, replace=False)] = 0.0  # zero slots: operations the walk skips
    q = rng.normal(size=(n_poses, chain.n_joints))
    return rng, chain, x, q


def _close(a, b, what):
    np.testing.assert_allclose(a, b, rtol=0, atol=1e-12 * max(1.0, np.abs(b).max()), err_msg=what)


@pytest.fixture(params=["stacked", "columns"])
def screws_path(request, monkeypatch):
    """Both ways of forming the screws: all rotations at once (few poses), or column by column."""
    monkeypatch.setattr(chain_walk, "STACKED_MAX", 10**9 if request.param == "stacked" else 0)
    return request.param


@pytest.mark.parametrize("kind", sorted(CHAINS))
def test_batch_kinematics_equal_the_reference_walk(kind, screws_path):
    rng, chain, x, q = _case(kind, 5)
    R_new, p_new, T_new = chain.forward_frames(x, q)
    R_ref, p_ref, T_ref = ref.forward_frames(chain, x, q)
    _close(R_new, R_ref, "R_before")
    _close(p_new, p_ref, "p_before")
    _close(T_new, T_ref, "forward_frames T")
    _close(chain.forward(x, q), ref.forward(chain, x, q), "forward")
    for offsets in (rng.normal(size=(3, 3)) * 60, rng.normal(size=(len(q), 2, 3)) * 60, None):
        new, old = chain.jacobians_walk(x, q, offsets), ref.jacobians_walk(chain, x, q, offsets)
        for field in ("T", "pose_slots", "pose_joints", "points", "point_slots", "point_joints"):
            a, b = getattr(new, field), getattr(old, field)
            assert (a is None) == (b is None), field
            if b is not None:
                assert a.shape == b.shape, field
                _close(a, b, field)
        if offsets is not None:
            _close(tool_points(new.T, offsets), ref.tool_points(old.T, offsets), "tool_points")


def test_batch_forward_equals_plain_dh_matrices():
    """A 6R chain against 4x4 products written out: base ZYX Euler + translation, links
    Rz(q + theta) Tz(d) Tx(a) Rx(alpha) Ry(beta), the last joint, the tool's Euler + translation."""
    rng, chain, x, q = _case("6R", 8, n_poses=5)

    def Ry(b):
        c, s = math.cos(b), math.sin(b)
        return np.array([[c, 0, s, 0], [0, 1, 0, 0], [-s, 0, c, 0], [0, 0, 0, 1.0]])

    def euler(v):
        return Rz(v[0]) @ Ry(v[1]) @ Rx(v[2]) @ Trans(*v[3:6])

    for qi, T in zip(q, chain.forward(x, q)):
        M = euler(x[:6])
        for k in range(5):
            th, d, beta, a, alpha = x[6 + 5 * k:11 + 5 * k]
            M = M @ Rz(qi[k] + th) @ Trans(0, 0, d) @ Trans(a, 0, 0) @ Rx(alpha) @ Ry(beta)
        M = M @ Rz(qi[5]) @ euler(x[31:37])
        _close(T, M, "forward against plain DH")


def test_batch_jacobians_equal_central_differences(screws_path):
    """Slot and reading Jacobians of tool points on a prismatic, coupled chain with a tool offset."""
    rng = np.random.default_rng(12)
    chain = Chain(("revolute", "prismatic", "revolute", "revolute", "revolute"),
                  joint_map=np.eye(5) + 0.2 * np.eye(5, k=-1), joint_offset=rng.normal(size=5),
                  tool_offset=np.array([[1, 0, 0, 3], [0, 0, -1, -4], [0, 1, 0, 9], [0, 0, 0, 1.0]]))
    x = rng.normal(size=chain.n_slots) * 100
    q = rng.normal(size=(4, chain.n_joints))
    offsets = rng.normal(size=(4, 2, 3)) * 50
    jac = chain.jacobians_walk(x, q, offsets)
    h = 1e-6
    for s in range(chain.n_slots):
        dx = np.zeros(chain.n_slots)
        dx[s] = h
        diff = (tool_points(chain.forward(x + dx, q), offsets) - tool_points(chain.forward(x - dx, q), offsets)) / (2 * h)
        np.testing.assert_allclose(jac.point_slots[..., s], diff, atol=1e-6 * max(1.0, np.abs(diff).max()))
    for j in range(chain.n_joints):
        dq = np.zeros(chain.n_joints)
        dq[j] = h
        diff = (tool_points(chain.forward(x, q + dq), offsets) - tool_points(chain.forward(x, q - dq), offsets)) / (2 * h)
        np.testing.assert_allclose(jac.point_joints[..., j], diff, atol=1e-6 * max(1.0, np.abs(diff).max()))


@pytest.mark.parametrize("kind", ["6R", "prismatic", "coupled_with_tool_offset"])
def test_projected_point_jacobians_are_the_point_jacobians_along_the_directions(kind):
    """u . (point Jacobians) without the point Jacobians: equal to the full ones projected, and to
    central differences of u . point; one pose too (there by the single-pose scan, projected)."""
    rng, chain, x, q = _case(kind, 21, n_poses=6)
    offsets = rng.normal(size=(len(q), 3)) * 80
    u = rng.normal(size=(len(q), 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    for rows in (slice(0, 1), slice(None)):  # one pose, then all (checked below by differences)
        points, along_slots, along_joints = chain.projected_point_jacobians(x, q[rows], offsets[rows], u[rows])
        full = chain.jacobians_walk(x, q[rows], offsets[rows, None, :])
        _close(points, full.points[:, 0], "points")
        _close(along_slots, np.einsum("mi,mis->ms", u[rows], full.point_slots[:, 0]), "along slots")
        _close(along_joints, np.einsum("mi,mij->mj", u[rows], full.point_joints[:, 0]), "along joints")
    h = 1e-6

    def along(xs, qs):
        return np.einsum("mi,mi->m", u, chain.projected_point_jacobians(xs, qs, offsets, u)[0])

    for s in range(chain.n_slots):
        dx = np.zeros(chain.n_slots)
        dx[s] = h
        diff = (along(x + dx, q) - along(x - dx, q)) / (2 * h)
        np.testing.assert_allclose(along_slots[:, s], diff, atol=1e-6 * max(1.0, np.abs(diff).max()))
    for j in range(chain.n_joints):
        dq = np.zeros(chain.n_joints)
        dq[j] = h
        diff = (along(x, q + dq) - along(x, q - dq)) / (2 * h)
        np.testing.assert_allclose(along_joints[:, j], diff, atol=1e-6 * max(1.0, np.abs(diff).max()))
    with pytest.raises(ValueError, match="directions must have shape"):
        chain.projected_point_jacobians(x, q, offsets, u[:2])
