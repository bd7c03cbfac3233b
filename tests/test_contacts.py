"""Contacts at fixture points and on planes (DESIGN.md 8.2): the graph's rows, written here from the
chain's tool poses, and their Jacobians against finite differences; the files' round trip and refusals,
the gauge, the result's set-up section, and verify's consistency against a computation written
here."""
import numpy as np
import pytest

from fgcal.errors import DatasetError
from fgcal.estimation.calibrate import GAUGE_REASON, CalibrationOptions, build_graph, calibrate
from fgcal.estimation.result import load_result, save_result
from fgcal.estimation.verification import verify
from fgcal.io.dataset_io import load_dataset, save_dataset
from fgcal.measurements.contact import ContactObservations
from fgcal.measurements.dataset import Dataset, Noise
from fgcal.measurements.setup import DistanceConstraint, FixtureSpec, SetupSpec, plane_normal
from fgcal.robots.model import Tooling

BALLS = {"B": np.array([10.0, -5.0, 60.0])}
RADIUS = 4.0


def _plain_centres(model, slots, q, offset):
    """Ball centres by the chain's 4x4 products: base, joints, tool (written here, not fgcal's kinematics)."""
    T = model.forward(slots, q)  # the chain itself is tested against plain DH in test_kinematics
    return np.einsum("nij,j->ni", T[:, :3, :3], offset) + T[:, :3, 3]


def _dataset(model, seed, n=24, plane=True, fixed=False):
    """Contacts at two points and (optionally) a plane, at random joint sets (the errors need not be
    zero for the Jacobian test)."""
    rng = np.random.default_rng(seed)
    lo, hi = model.joint_limits[:, 0], model.joint_limits[:, 1]
    q = rng.uniform(np.maximum(lo, -2.5), np.minimum(hi, 2.5), size=(n, model.n_joints))
    kinds = np.array(["s0", "s1", "table"] if plane else ["s0", "s1"])
    fixture = kinds[np.arange(n) % len(kinds)]
    fixtures = {"s0": FixtureSpec("s0", "point", np.array([400.0, 0, 0]) if fixed else None, None, fixed),
                "s1": FixtureSpec("s1", "point")}
    if plane:
        fixtures["table"] = FixtureSpec("table", "plane")
    ds = Dataset(robot=model.name, tooling=Tooling(RADIUS, BALLS),
                 noise=Noise(cmm_sigma=0.01, joint_resolution=0.0, extra=(("contact_sigma", 0.02),)),
                 provenance={}, pose_ids=np.arange(1, n + 1), joints_deg=model.joints_to_file_units(q),
                 setup=SetupSpec(fixtures, (DistanceConstraint("s0", "s1", 50.0, 0.01),)))
    pt = fixture != "table"
    ds.contacts = ContactObservations(ds.pose_ids[pt], np.full(pt.sum(), "B"), fixture[pt])
    if plane:
        ds.plane_contacts = ContactObservations(ds.pose_ids[~pt], np.full((~pt).sum(), "B"), fixture[~pt])
    return ds, q


def test_rows_and_jacobians_against_plain_kinematics(puma):
    ds, q = _dataset(puma, 1)
    graph, state, _ = build_graph(ds, puma, puma.parameters().names, CalibrationOptions(joint_noise=False))
    rng = np.random.default_rng(7)
    state.theta = state.theta + rng.normal(scale=1e-3, size=state.theta.shape)  # a random point, not the start
    lin = graph.linearise(state)
    layout = graph.setup
    sig = graph.sigmas.contact

    def rows(theta):
        x = graph.params.full(theta, graph.held)
        s = layout.full(theta[graph.n_geo:])
        out = []
        for level in ("contacts", "plane_contacts"):
            obs = getattr(ds, level)
            c = _plain_centres(puma, x, q[ds.row_of(obs.pose)], BALLS["B"])
            for ci, f in zip(c, obs.fixture):
                if level == "contacts":
                    out.append((ci - layout.point(s, f)) / sig)
                else:
                    n, d = layout.plane(s, f)
                    out.append(np.array([ci @ n - d - RADIUS]) / sig)
        return out

    r = []
    J = []
    for level in ("contacts", "plane_contacts"):
        pose, rws = graph.factor_rows(level)
        r += list(lin.r[pose[:, None], rws])
        J += list(lin.J_theta[pose[:, None], rws])
    assert np.allclose(np.concatenate(r), np.concatenate(rows(state.theta)), atol=1e-9)
    h = 1e-6
    J_num = np.array([(np.concatenate(rows(state.theta + h * e)) - np.concatenate(rows(state.theta - h * e))) / (2 * h)
                      for e in np.eye(len(state.theta))]).T
    J = np.concatenate(J)
    assert np.allclose(J, J_num, rtol=1e-5, atol=1e-5 * np.abs(J_num).max())
    # the known distance: one global row, its Jacobian by differences too
    c_r, c_J, _ = graph.constraint_rows(state.theta)

    def dist_row(theta):
        s = layout.full(theta[graph.n_geo:])
        return (np.linalg.norm(layout.point(s, "s0") - layout.point(s, "s1")) - 50.0) / 0.01

    assert c_r[0] == pytest.approx(dist_row(state.theta))
    num = np.array([(dist_row(state.theta + h * e) - dist_row(state.theta - h * e)) / (2 * h)
                    for e in np.eye(len(state.theta))])
    assert np.allclose(c_J[0], num, atol=1e-4)


def test_plane_normal_derivative():
    rng = np.random.default_rng(3)
    for _ in range(5):
        n0 = rng.normal(size=3)
        n0 /= np.linalg.norm(n0)
        t = rng.normal(scale=0.2, size=2)
        n, dn = plane_normal(n0, t)
        assert np.linalg.norm(n) == pytest.approx(1.0)
        h = 1e-7
        num = np.column_stack([(plane_normal(n0, t + h * e)[0] - plane_normal(n0, t - h * e)[0]) / (2 * h)
                               for e in np.eye(2)])
        assert np.allclose(dn, num, atol=1e-7)


def test_files_round_trip_and_refusals(puma, tmp_path):
    ds, _ = _dataset(puma, 2)
    save_dataset(ds, tmp_path / "c")
    text = (tmp_path / "c" / "contacts.csv").read_text().splitlines()
    assert text[0] == "pose,ball,fixture" and len(text) == 1 + ds.n_poses  # both kinds in one file
    back = load_dataset(tmp_path / "c")
    assert np.array_equal(back.contacts.fixture, ds.contacts.fixture)
    assert np.array_equal(back.plane_contacts.pose, ds.plane_contacts.pose)
    assert back.setup.distances == ds.setup.distances and set(back.setup.fixtures) == {"s0", "s1", "table"}
    assert dict(back.noise.extra)["contact_sigma"] == 0.02
    # an unknown fixture is named with its line
    (tmp_path / "c" / "contacts.csv").write_text("pose,ball,fixture\n1,B,s0\n2,B,nowhere\n")
    with pytest.raises(DatasetError, match=r"contacts.csv: line 3: fixture 'nowhere' is not in"):
        load_dataset(tmp_path / "c")
    yaml_path = tmp_path / "c" / "dataset.yaml"
    yaml_text = yaml_path.read_text()
    yaml_path.write_text(yaml_text.replace("s1: {type: point}", "s1: {type: cone}"))
    with pytest.raises(DatasetError, match="fixtures.'s1'|fixtures.s1"):
        load_dataset(tmp_path / "c")
    yaml_path.write_text(yaml_text.replace("[s0, s1, 50.0, 0.01]", "[s0, table, 50.0, 0.01]"))
    with pytest.raises(DatasetError, match="is not a point fixture"):
        load_dataset(tmp_path / "c")


def _exact_contacts(model, truth_slots, seed, n_per=12):
    """Joint sets whose true ball centres sit exactly on two sockets: each socket's contacts are
    found by solving for joints 1-3 (position) at random wrist joints, with plain Newton steps."""
    rng = np.random.default_rng(seed)
    sockets = {"s0": np.array([450.0, 150.0, -100.0]), "s1": np.array([450.0, 200.0, -100.0])}
    q_all, fx = [], []
    for name, p in sockets.items():
        found = 0
        while found < n_per:
            q = rng.uniform(-1.5, 1.5, size=model.n_joints)
            for _ in range(40):
                c = _plain_centres(model, truth_slots, q[None], BALLS["B"])[0]
                J = np.column_stack([(_plain_centres(model, truth_slots, (q + 1e-6 * e)[None], BALLS["B"])[0] - c) / 1e-6
                                     for e in np.eye(model.n_joints)[:3]])
                q[:3] -= np.linalg.lstsq(J, c - p, rcond=None)[0]
            if np.linalg.norm(_plain_centres(model, truth_slots, q[None], BALLS["B"])[0] - p) < 1e-9 \
                    and np.all(np.abs(q) < np.pi):
                q_all.append(q.copy())
                fx.append(name)
                found += 1
    return np.array(q_all), np.array(fx), sockets


def test_exact_contacts_calibrate_to_zero_and_verify_consistency(puma, tmp_path):
    """Noise-free contacts of a perturbed PUMA: the solve drives the contacts to zero, the gauge
    holds the base and says so, and verify's consistency equals the spread computed here."""
    rng = np.random.default_rng(11)
    truth = puma.nominal.copy()
    link = np.array([not n.startswith(("base.", "tool.")) for n in puma.slot_names])
    truth[link] += np.where(puma.slot_is_angle[link], np.radians(0.05), 0.3) * rng.normal(size=link.sum())
    q, fx, sockets = _exact_contacts(puma, truth, 5)
    n = len(q)
    ds = Dataset(robot="puma560", tooling=Tooling(0.0, BALLS),
                 noise=Noise(cmm_sigma=0.01, joint_resolution=0.0, extra=(("contact_sigma", 0.01),)), provenance={},
                 pose_ids=np.arange(1, n + 1), joints_deg=np.degrees(q),
                 setup=SetupSpec({k: FixtureSpec(k, "point") for k in sockets},
                                 (DistanceConstraint("s0", "s1", 50.0, 1e-4),)))
    ds.contacts = ContactObservations(ds.pose_ids, np.full(n, "B"), fx)
    res = calibrate(ds, puma, CalibrationOptions(noise="declared", outliers="none"))
    held = {h["name"]: h["reason"] for h in res.held}
    assert all(held.get(f"base.{c}") == GAUGE_REASON for c in ("phi", "theta", "psi", "px", "py", "pz"))
    assert res.setup["gauge"] == GAUGE_REASON
    assert np.sqrt(np.mean(np.square(res.residuals["contacts_mm"]))) < 1e-6
    est = res.setup["estimated"]
    assert abs(np.linalg.norm(np.subtract(est["s0"]["position"], est["s1"]["position"])) - 50.0) < 1e-5
    save_result(res, tmp_path / "r.json")
    back = load_result(tmp_path / "r.json")
    assert back.setup == res.setup and back.names == res.names
    ver = verify(back, ds, puma).to_dict()
    assert ver["consistency_mm"]["rms"] < 1e-6 and abs(ver["distance_mm"]["mean_abs"]) < 1e-5
    # before: the nominal model's spread, computed here
    c_nom = _plain_centres(puma, puma.nominal, q, BALLS["B"])
    spread = np.concatenate([np.linalg.norm(c_nom[fx == k] - c_nom[fx == k].mean(0), axis=1) for k in sockets])
    assert ver["before"]["consistency_mm"]["rms"] == pytest.approx(np.sqrt(np.mean(spread**2)), rel=1e-9)
    d_nom = np.linalg.norm(c_nom[fx == "s0"].mean(0) - c_nom[fx == "s1"].mean(0)) - 50.0
    assert ver["before"]["distance_mm"]["mean_abs"] == pytest.approx(abs(d_nom), rel=1e-9)
