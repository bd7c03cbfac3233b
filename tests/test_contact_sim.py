"""The independent contact-data generator (tests/contact_sim.py) checked on its own: its URDF
forward kinematics against yourdfpy, the perturbation, and the datasets it writes (seatings at
their sockets, sockets their distance apart, varied joint sets, plane contacts a radius from the
plane). It does not use fgcal."""
import csv
import time
import xml.etree.ElementTree as ET
from pathlib import Path

import contact_sim as cs
import numpy as np
import pytest
import yaml

yourdfpy = pytest.importorskip("yourdfpy", reason="yourdfpy (test extra) checks the FK independently")

DATA = Path(__file__).parent / "data" / "urdf"
ROBOTS = {
    "panda": ("panda.urdf", {"base": "panda_link0", "tip": "panda_hand_tcp"}, 7),
    "ur10": ("ur10_robot.urdf", {"base": "base_link", "tip": "tool0"}, 6),
    "kinova": ("kinova.urdf", {"tip": "j2s6s200_end_effector"}, 6),
}
BALL = np.array([0.0, 0.0, 30.0])


def _yourdfpy_fk(text, chain, q, tmp_path):
    """Tip poses (mm) in the base link by yourdfpy at joint sets ``q`` (rad, mm)."""
    path = tmp_path / "check.urdf"
    path.write_text(text)
    u = yourdfpy.URDF.load(str(path), load_meshes=False, load_collision_meshes=False)
    out = []
    for qi in q:
        u.update_cfg({n: v if t == "revolute" else v / 1000.0
                      for n, t, v in zip(chain.joint_names, chain.joint_types, qi)})
        T = u.get_transform(chain.tip, chain.base).copy()
        T[:3, 3] *= 1000.0
        out.append(T)
    return np.array(out)


def _chain(robot, text=None):
    name, chain, _ = ROBOTS[robot]
    return cs.UrdfChain(text or (DATA / name).read_text(), chain.get("base"), chain.get("tip"))


@pytest.mark.parametrize("robot", sorted(ROBOTS))
def test_forward_kinematics_matches_yourdfpy(robot, tmp_path):
    chain = _chain(robot)
    assert chain.n == ROBOTS[robot][2] and set(chain.joint_types) == {"revolute"}
    rng = np.random.default_rng(11)
    q = cs._sample_joints(chain, rng, 25)
    ours = chain.fk(q)
    assert np.abs(_yourdfpy_fk((DATA / ROBOTS[robot][0]).read_text(), chain, q, tmp_path) - ours).max() < 1e-9
    # the perturbed copy too (its origins are written with full precision)
    text = cs.perturbed_urdf((DATA / ROBOTS[robot][0]).read_text(), rng, chain.base, chain.tip)
    true = cs.UrdfChain(text, chain.base, chain.tip)
    assert np.abs(_yourdfpy_fk(text, true, q, tmp_path) - true.fk(q)).max() < 1e-9
    # point and its Jacobian against central differences
    p, _T, J = chain.point_and_jacobian(q[0], BALL)
    assert np.allclose(p, chain.point(q[0], BALL), atol=1e-12)
    h = 1e-6
    num = np.array([(chain.point(q[0] + h * e, BALL) - chain.point(q[0] - h * e, BALL)) / (2 * h)
                    for e in np.eye(chain.n)]).T
    assert np.abs(num - J).max() < 1e-5


@pytest.mark.parametrize("robot", sorted(ROBOTS))
def test_perturbation_moves_every_chain_joint_and_nothing_else(robot):
    name, spec, _ = ROBOTS[robot]
    text = (DATA / name).read_text()
    nominal = _chain(robot)
    chain_joints = {j.name for j in nominal.joints}
    true_text = cs.perturbed_urdf(text, np.random.default_rng(3), nominal.base, nominal.tip)
    a = {e.get("name"): e for e in ET.fromstring(text).findall("joint")}
    b = {e.get("name"): e for e in ET.fromstring(true_text).findall("joint")}
    assert a.keys() == b.keys()
    dxyz, drpy = [], []
    for n in a:
        oa, ob = a[n].find("origin"), b[n].find("origin")
        xa = cs._floats(oa.get("xyz") if oa is not None else None, [0, 0, 0])
        ra = cs._floats(oa.get("rpy") if oa is not None else None, [0, 0, 0])
        xb = cs._floats(ob.get("xyz") if ob is not None else None, [0, 0, 0])
        rb = cs._floats(ob.get("rpy") if ob is not None else None, [0, 0, 0])
        if n in chain_joints:
            dxyz.append((xb - xa) * 1000.0)
            drpy.append(np.degrees(rb - ra))
        else:
            assert np.array_equal(xa, xb) and np.array_equal(ra, rb)
        assert a[n].get("type") == b[n].get("type")
    dxyz, drpy = np.array(dxyz), np.array(drpy)
    assert np.all(dxyz != 0.0) and np.all(drpy != 0.0)  # fixed joints of the chain too
    assert 0.2 < dxyz.std() < 1.0 and 0.02 < drpy.std() < 0.1
    assert np.array_equal(cs.UrdfChain(true_text, nominal.base, nominal.tip).limits, nominal.limits)


def _read_dataset(d):
    meta = yaml.safe_load((d / "dataset.yaml").read_text())
    with open(d / "joints.csv") as f:
        joints = list(csv.reader(f))
    with open(d / "contacts.csv") as f:
        contacts = list(csv.reader(f))
    return meta, joints, contacts


def _check_files(d, truth, urdf, n_joints):
    meta, joints, contacts = _read_dataset(d)
    assert meta["format"] == "fgcal-dataset/1" and meta["robot"] == "robot.urdf"
    assert (d / "robot.urdf").read_text() == urdf.read_text()  # the nominal robot
    assert meta["chain"] == truth.chain
    assert meta["tool"]["balls"] == {"B": [float(v) for v in truth.ball]}
    assert meta["provenance"]["generator"] == "tests/contact_sim.py"
    assert joints[0] == ["pose"] + [f"q{k}" for k in range(1, n_joints + 1)]
    assert [int(r[0]) for r in joints[1:]] == list(range(1, len(truth.poses) + 1))
    assert np.array_equal(np.array([[float(v) for v in r[1:]] for r in joints[1:]]), truth.readings)
    assert contacts[0] == ["pose", "ball", "fixture"]
    assert [(int(p), b, f) for p, b, f in contacts[1:]] == [(int(p), "B", f) for p, f in zip(truth.poses, truth.fixtures)]
    assert set(truth.fixtures) == set(meta["fixtures"])
    return meta


def _check_true_centres(truth, sigma_q_deg):
    true = cs.UrdfChain(truth.urdf, truth.chain["base"], truth.chain["tip"])
    assert np.all(truth.q >= true.limits[:, 0]) and np.all(truth.q <= true.limits[:, 1])
    centres = true.point(truth.q, truth.ball)
    assert np.abs(centres - truth.centres).max() < 1e-9  # the IK hit its targets exactly
    noise = truth.readings - true.to_readings(truth.q)
    assert np.abs(noise).max() <= 5 * sigma_q_deg
    if sigma_q_deg > 0:
        assert 0.5 * sigma_q_deg < noise.std() < 1.5 * sigma_q_deg
    return true, centres


@pytest.mark.parametrize("robot,placements,configs", [("panda", 3, 15), ("ur10", 2, 6), ("kinova", 2, 6)])
def test_two_socket_dataset(robot, placements, configs, tmp_path):
    name, spec, n = ROBOTS[robot]
    sigma, sigma_q, dist = 0.02, 0.005, 50.0
    t0 = time.perf_counter()
    truth = cs.two_socket_dataset(tmp_path / "ds", DATA / name, spec, np.random.default_rng(5), placements,
                                  configs, BALL, sigma, sigma_q, dist, seed=5)
    assert time.perf_counter() - t0 < 15.0
    meta = _check_files(tmp_path / "ds", truth, DATA / name, n)
    assert meta["tool"]["radius"] == 0.0
    assert meta["noise"] == {"cmm_sigma": 0.01, "joint_resolution": 0.0, "repeatability": sigma_q,
                             "contact_sigma": sigma}
    assert meta["fixtures"] == {f"p{k}/hole_{j}": {"type": "point"} for k in range(placements) for j in (0, 1)}
    assert meta["constraints"]["distances"] == [[f"p{k}/hole_0", f"p{k}/hole_1", dist, 0.005]
                                                for k in range(placements)]
    assert len(truth.poses) == placements * 2 * configs
    true, centres = _check_true_centres(truth, sigma_q)
    sockets = np.array([truth.sockets[f] for f in truth.fixtures])
    off = centres - sockets
    assert np.abs(off).max() < 5 * sigma and 0.5 * sigma < off.std() < 1.5 * sigma
    for k in range(placements):
        a, b = truth.sockets[f"p{k}/hole_0"], truth.sockets[f"p{k}/hole_1"]
        assert abs(np.linalg.norm(a - b) - dist) < 1e-9 and abs(a[2] - b[2]) < 1e-9
    for f in truth.sockets:
        q = true.to_readings(truth.q[[i for i, g in enumerate(truth.fixtures) if g == f]])
        assert len(q) == configs
        sep = np.linalg.norm(q[:, None] - q[None], axis=2)[np.triu_indices(configs, 1)]
        assert sep.min() > 5.0
        R = true.fk(true.from_readings(q))[:, :3, :3]
        turn = [cs._rotation_angle_deg(R[i], R[j]) for i, j in zip(*np.triu_indices(configs, 1))]
        assert min(turn) > 5.0 and max(turn) > 45.0  # the last links' orientations vary
    # the nominal robot is off by about a millimetre at these readings, beyond any rigid motion
    nominal = _chain(robot)
    assert cs.aligned_rms(nominal.point(nominal.from_readings(truth.readings), truth.ball), sockets) > 0.1


@pytest.mark.parametrize("robot", ["panda", "kinova"])
def test_plane_dataset(robot, tmp_path):
    name, spec, n = ROBOTS[robot]
    r, sigma, count = 4.0, 0.02, 30
    truth = cs.plane_dataset(tmp_path / "ds", DATA / name, spec, np.random.default_rng(8), count, r, BALL,
                             sigma, 0.005, seed=8)
    meta = _check_files(tmp_path / "ds", truth, DATA / name, n)
    assert meta["tool"]["radius"] == r and meta["fixtures"] == {"table": {"type": "plane"}}
    assert "constraints" not in meta and set(truth.fixtures) == {"table"} and len(truth.poses) == count
    true, centres = _check_true_centres(truth, 0.005)
    normal, d = truth.plane
    assert abs(np.linalg.norm(normal) - 1.0) < 1e-12 and normal[2] > np.cos(np.radians(10.0))
    height = centres @ normal - d  # on the normal's side, a radius off the plane
    assert np.abs(height - r).max() < 5 * sigma
    # spread over the plane
    u, v = cs._orthonormal(normal)
    spread = np.c_[centres @ u, centres @ v]
    assert np.ptp(spread, axis=0).min() > 200.0
    # the tool stands above the table: the flange on the normal's side of the ball
    flange = true.fk(truth.q)[:, :3, 3]
    assert np.all((flange - centres) @ normal > 0.0)


def test_same_seed_same_dataset_and_stems_up(tmp_path):
    """The same seed writes the same files; with max_tilt_deg every stem is that close to vertical."""
    name, spec, _ = ROBOTS["ur10"]
    runs = [cs.two_socket_dataset(tmp_path / d, DATA / name, spec, np.random.default_rng(6), 1, 5, BALL, 0.02,
                                  0.01, seed=6, max_tilt_deg=60.0) for d in ("a", "b")]
    for f in ("dataset.yaml", "joints.csv", "contacts.csv", "robot.urdf"):
        assert (tmp_path / "a" / f).read_text() == (tmp_path / "b" / f).read_text()
    assert runs[0].urdf == runs[1].urdf and np.array_equal(runs[0].q, runs[1].q)
    assert yaml.safe_load((tmp_path / "a" / "dataset.yaml").read_text())["provenance"]["seed"] == 6
    true = cs.UrdfChain(runs[0].urdf, spec["base"], spec["tip"])
    T = true.fk(runs[0].q)
    stem = -(T[:, :3, :3] @ BALL)
    assert np.all(stem[:, 2] / np.linalg.norm(stem, axis=1) >= np.cos(np.radians(60.0)) - 1e-12)


def test_new_poses_are_the_true_robot(tmp_path):
    name, spec, _ = ROBOTS["panda"]
    text = cs.perturbed_urdf((DATA / name).read_text(), np.random.default_rng(1), spec["base"], spec["tip"])
    poses = cs.new_poses(text, spec, BALL, np.random.default_rng(2), 10)
    true = cs.UrdfChain(text, spec["base"], spec["tip"])
    T = _yourdfpy_fk(text, true, poses.q, tmp_path)
    assert np.abs(T[:, :3, :3] @ BALL + T[:, :3, 3] - poses.points).max() < 1e-9
    assert np.allclose(true.from_readings(poses.readings), poses.q)
    assert np.all(poses.q >= true.limits[:, 0]) and np.all(poses.q <= true.limits[:, 1])


def test_rigid_alignment():
    rng = np.random.default_rng(4)
    P = rng.normal(0, 300.0, (40, 3))
    A, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    A *= np.sign(np.linalg.det(A))
    t = np.array([1000.0, -200.0, 50.0])
    Q = P @ A.T + t
    R, t_fit = cs.rigid_align(P, Q)
    assert np.abs(R - A).max() < 1e-12 and np.abs(t_fit - t).max() < 1e-9
    assert cs.aligned_rms(P, Q) < 1e-9
    noisy = Q + rng.normal(0, 0.01, Q.shape)
    assert 0.01 < cs.aligned_rms(P, noisy) < 0.02
    # a mirror image is no rigid motion
    assert cs.aligned_rms(P * [1, 1, -1], Q) > 10.0
