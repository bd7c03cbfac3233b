"""Cost per equation of the measurement types of the third round against the point type.

A built-in UR10 (its geometry perturbed by typical deviations) is measured four ways, each with
about the same number of equations (rows of the least squares):

* ``centres``: one tracker reflector, 3 rows a pose (the reference);
* ``contacts``: the tool ball seated in the two sockets of plates at several placements, 3 rows a
  contact, a known 50 mm distance between the sockets of a plate, every socket an unknown point;
* ``plane_contacts``: the ball touching three unknown planes, 1 row a touch;
* ``station_centres``: one reflector seen from three tracker stations, two of them unknown frames.

Each dataset is written in fgcal's format and calibrated by :func:`fgcal.estimation.calibrate.calibrate`
at the default options; the figure is process CPU time (user + system, least of ``--repeat`` interleaved rounds) per
equation, and its ratio to the point type's; beside it the same CPU per pose and its ratio (every pose
costs one forward kinematics and Jacobian a linearisation, whatever its rows). The datasets declare
``joint_resolution: 0``: the joint readings are exact, so there are no joint variables and no joint rows
(declared 0.001 deg, the noise rounds took 35-40 rounds, the limit, until they stepped by quasi-Newton,
fgcal.estimation.variance_steps: 8-11 rounds, the joints' noise at its floor where the readings are exact).
Contact poses are found by a damped least-squares IK on the perturbed model (not timed). Single-threaded BLAS.

Noise, two cases (``--noise``), the same for every type: ``as-declared``, each dataset's noise is the 0.01 mm
it declares (centres and stations: in each coordinate; contacts: the ball's seating about its socket, each
axis; planes: along the normal; seated by the minimum-norm joint change, so the readings carry it);
``misdeclared``, three times that, so every type's noise estimation moves its sigma and solves again. (Until
round 3's fifth session the contacts and planes carried 0.002 deg of joint noise, 2.3-2.7 times the 0.01 mm
they declared, against centres whose noise was as declared: they paid a noise round the point type did not.)

Measured (round 3, session 5; ``--rows 3000 --repeat 5``, sequential best-of runs, 2 shared cores, +-10 %), CPU
per equation against the point type: as declared, stations 1.03-1.1, contacts 1.59-1.8, planes 1.02-1.14 (per
pose 0.34); misdeclared, stations 1.0-1.5, contacts 1.7-2.05, planes 1.1-1.4.

Measured (round 3, session 6; ``--rows 3000 --repeat 20``, interleaved rounds, the session's last code, two
runs and one interleaved run of the calibrations alone): the point type itself became 1.3x faster (12.7 -> 9.2-9.3
us a row: its base-fit points by views of one sort, the final covariance and identifiability sharing one inverse
and one eigenvalue decomposition), so the ratios rose where every type's own time fell. As declared: stations
12.2 us a row (was 17.0), 1.32-1.34; contacts 14.1 (was 23.5), 1.49-1.52 (the session's starting code, measured
the same way: 1.82-1.89); planes 14.6 (was 16.5), 1.58-1.65, per pose 0.53. Misdeclared: stations 1.37,
contacts 1.55, planes 1.69. Runs earlier in the session (before its last two changes, helpers busy beside
them) gave up to 1.39 / 1.67 / 1.74: the machine's noise is of that size.

Not met: as fast per row as the point type. What is left, measured (one linearisation, its normal equations and
a step at the solution, least of 7 x 10): stations and contacts take one more LM iteration (6 against 5: the
second noise round moves their optimum, the set-up priors' and distances' weight against the data changing with
the noise, where the point type's does not move), 2.0 ms for contacts and 2.3 ms for stations, ~5 % of a
calibration; a station linearisation costs 1.5x a centres one (1.96 against 1.29 ms: the frames' transforms and
their columns), over the 8 of a calibration ~5 ms; contacts' normal equations cost 0.39 ms against 0.20 (per-pose
products on 24 columns, PoseColumns.inner: numpy's floor for 1,000 small products) and their set-up
identifiability (marginal_information) 0.45 ms twice; a plane touch is one row for a whole pose's kinematics
where a centre is three, so per row it pays three times the kinematics (per pose it costs half the point type's).

Run: ``python bench/bench_types.py [--rows 3000] [--repeat 10] [--data DIR]`` (``--data``: the datasets are
kept in DIR and reused by later runs with the same ``--rows`` and ``--seed``; generating 3,000 rows takes minutes).
"""
from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import numpy as np  # noqa: E402
import yaml  # noqa: E402
from scipy.optimize import least_squares  # noqa: E402

BALL = np.array([10.0, -5.0, 60.0])  # the ball (or reflector) on the flange, mm
RADIUS = 6.35
SIGMA = 0.01  # mm
# The true noise of each case where every dataset declares SIGMA (centres and stations: in each
# coordinate; contacts: the ball's seating about its socket, each axis; planes: along the normal).
NOISE_CASES = {"as-declared": SIGMA, "misdeclared": 3 * SIGMA}
STATIONS = {"B": [30.0, 2.0, -1.0, 800.0, -300.0, 50.0], "C": [-60.0, -1.5, 3.0, -200.0, 900.0, -20.0]}


def _truth(model, rng):
    from fgcal.robots.deviations import Deviations

    x = model.nominal.copy()
    names = model.identifiable_names()
    sig = Deviations().sigmas(names)
    for n, s in zip(names, sig):  # mm and rad, as the slots
        x[model.slot(n)] += rng.normal() * s
    return x


def _centre(model, x, q):
    T = model.forward(x, np.atleast_2d(q))
    return np.einsum("nij,j->ni", T[:, :3, :3], BALL) + T[:, :3, 3]


def _ik(model, x, q0, A, b):
    """Joints near ``q0`` where the ball centre c satisfies ``A c = b`` (a point: A = I; a plane: its
    normal), by a trust-region least squares from ``q0`` with the chain's analytic Jacobian."""
    from fgcal.robots.kinematics import jacobians

    lo, hi = model.joint_limits[:, 0], model.joint_limits[:, 1]
    chain = model.chain

    def fun(q):
        return A @ _centre(model, x, q)[0] - b

    def jac(q):
        J = jacobians(x, q[None], offsets=BALL[None, None], chain=chain).point_joints[0, 0]
        return A @ J

    sol = least_squares(fun, q0, jac=jac, bounds=(lo, hi), xtol=1e-15, ftol=1e-15, gtol=1e-15, max_nfev=100)
    return sol.x, float(np.abs(fun(sol.x)).max())


def _joints(model, rng, n):
    lo, hi = np.maximum(model.joint_limits[:, 0], -2.8), np.minimum(model.joint_limits[:, 1], 2.8)
    return rng.uniform(lo, hi, size=(n, model.n_joints))


def _write(out: Path, model, q, *, centres=None, contacts=None, meta=None, station=None):
    out.mkdir(parents=True)
    ids = np.arange(1, len(q) + 1)
    data = {"format": "fgcal-dataset/1", "robot": model.name,
            "tool": {"radius": RADIUS, "balls": {"B": [float(v) for v in BALL]}},
            "noise": {"cmm_sigma": SIGMA, "joint_resolution": 0.0}, "provenance": {"generator": "bench_types"}}
    data.update(meta or {})
    (out / "dataset.yaml").write_text(yaml.safe_dump(data))
    qf = model.joints_to_file_units(q)
    head = "pose," + ",".join(f"q{i + 1}" for i in range(q.shape[1])) + (",station" if station is not None else "")
    rows = [f"{p}," + ",".join(repr(float(v)) for v in r) + (f",{station[k]}" if station is not None else "")
            for k, (p, r) in enumerate(zip(ids, qf))]
    (out / "joints.csv").write_text(head + "\n" + "\n".join(rows) + "\n")
    if centres is not None:
        (out / "centres.csv").write_text("pose,ball,x,y,z\n" + "\n".join(
            f"{p},B," + ",".join(repr(float(v)) for v in c) for p, c in zip(ids, centres)) + "\n")
    if contacts is not None:
        (out / "contacts.csv").write_text("pose,ball,fixture\n" + "\n".join(
            f"{p},B,{f}" for p, f in zip(ids, contacts)) + "\n")


def _seated(model, x, q, A, rng, sigma):
    """Readings (M, n) that seat the ball off its target ``q`` (M, n) by a normal error of ``sigma`` (mm) in
    each measured direction ``A`` (k, 3) or (M, k, 3) (a socket: the 3 axes; a plane: its normal), by the
    minimum-norm joint change (first order: the ball's error is the drawn one to ~1e-6 mm at 0.03 mm)."""
    from fgcal.robots.kinematics import jacobians

    J = np.matmul(A, jacobians(x, q, offsets=BALL[None], chain=model.chain).point_joints[:, 0])  # (M, k, n)
    delta = rng.normal(size=(len(q), A.shape[-2])) * sigma
    return q + np.einsum("mnk,mk->mn", np.linalg.pinv(J), delta)


def make_centres(root, model, x, rng, rows, sigma=SIGMA):
    q = _joints(model, rng, rows // 3)
    c = _centre(model, x, q) + rng.normal(size=(len(q), 3)) * sigma
    _write(root / "centres", model, q, centres=c)
    return 3 * len(q)


def make_stations(root, model, x, rng, rows, sigma=SIGMA):
    from fgcal.robots.transforms import euler_zyx_trans

    q = _joints(model, rng, rows // 3)
    c = _centre(model, x, q)
    names = np.array(["A", "B", "C"])[np.arange(len(q)) % 3]
    m = c.copy()
    for s, e in STATIONS.items():
        T = euler_zyx_trans(*np.radians(e[:3]), *e[3:])
        sel = names == s
        m[sel] = (c[sel] - T[:3, 3]) @ T[:3, :3]  # the point in the station's frame
    m += rng.normal(size=m.shape) * sigma
    _write(root / "stations", model, q, centres=m, station=names, meta={"stations": ["A", "B", "C"]})
    return 3 * len(q)


def make_contacts(root, model, x, rng, rows, sigma=SIGMA, per_socket=15):
    n_sockets = max(2, rows // 3 // per_socket // 2 * 2)
    q_all, fixture, fixtures, distances = [], [], {}, []
    for k in range(n_sockets // 2):
        for _attempt in range(50):  # a plate: two sockets 50 mm apart at a reachable place
            q0 = _joints(model, rng, 1)[0]
            a = _centre(model, x, q0)[0]
            u = rng.normal(size=3)
            b = a + 50.0 * u / np.linalg.norm(u)
            qs = []
            for target in (a, b):
                for _ in range(per_socket):
                    start = np.clip(q0 + rng.normal(size=q0.shape) * 0.35, model.joint_limits[:, 0],
                                    model.joint_limits[:, 1])
                    qk, err = _ik(model, x, start, np.eye(3), target)
                    if err < 1e-6:
                        qs.append((qk, target))
            if sum(1 for _, t in qs if t is a) >= 6 and sum(1 for _, t in qs if t is b) >= 6:
                break
        else:
            raise RuntimeError("no reachable plate in 50 attempts")
        for qk, t in qs:
            q_all.append(qk)
            fixture.append(f"plate{k}/hole_{0 if t is a else 1}")
        fixtures[f"plate{k}/hole_0"] = {"type": "point"}
        fixtures[f"plate{k}/hole_1"] = {"type": "point"}
        distances.append([f"plate{k}/hole_0", f"plate{k}/hole_1", 50.0, 0.005])
    q = np.array(q_all)
    meta = {"fixtures": fixtures, "constraints": {"distances": distances},
            "noise": {"cmm_sigma": SIGMA, "joint_resolution": 0.0, "contact_sigma": SIGMA}}
    q_read = _seated(model, x, q, np.eye(3), rng, sigma)  # the seating error, through the joints
    _write(root / "contacts", model, q_read, contacts=fixture, meta=meta)
    return 3 * len(q) + len(distances)


def make_planes(root, model, x, rng, rows, sigma=SIGMA):
    q_all, fixture = [], []
    planes = {}
    for k in range(3):
        q0 = _joints(model, rng, 1)[0]
        n = rng.normal(size=3)
        n /= np.linalg.norm(n)
        d = float(n @ _centre(model, x, q0)[0]) - RADIUS  # the ball touches it at q0
        planes[f"table{k}"] = (n, d)
    names = list(planes)
    for _attempt in range(20 * rows):
        if len(q_all) >= rows:
            break
        name = names[len(q_all) % 3]
        n, d = planes[name]
        qk, err = _ik(model, x, _joints(model, rng, 1)[0], n[None], np.array([d + RADIUS]))
        if err < 1e-6:
            q_all.append(qk)
            fixture.append(name)
    q = np.array(q_all)
    meta = {"fixtures": {n: {"type": "plane"} for n in names},
            "noise": {"cmm_sigma": SIGMA, "joint_resolution": 0.0, "contact_sigma": SIGMA}}
    normals = np.array([planes[f][0] for f in fixture])
    q_read = _seated(model, x, q, normals[:, None, :], rng, sigma)
    _write(root / "planes", model, q_read, contacts=fixture, meta=meta)
    return len(q)


def _datasets(root: Path, model, x, rng, n_rows: int, sigma: float) -> dict[str, int]:
    """The four datasets under ``root``, their noise ``sigma`` (mm) where they declare SIGMA, and their
    equation counts; ones already there (from an earlier run with the same ``--rows`` and ``--seed``)
    are reused, not generated again."""
    import json

    saved = root / "rows.json"
    if saved.exists():
        return {k: int(v) for k, v in json.loads(saved.read_text()).items()}
    root.mkdir(parents=True, exist_ok=True)
    rows = {"centres": make_centres(root, model, x, rng, n_rows, sigma),
            "stations": make_stations(root, model, x, rng, n_rows, sigma),
            "contacts": make_contacts(root, model, x, rng, n_rows, sigma),
            "planes": make_planes(root, model, x, rng, n_rows, sigma)}
    saved.write_text(json.dumps(rows))
    return rows


def cpu_of(paths, repeat):
    """Least process CPU time (s) of a default calibration of each dataset of ``paths``, and its result.

    Interleaved: after one warm-up calibration each, ``repeat`` rounds calibrate every dataset once,
    so that a slow spell of the shared machine falls on all the types alike (sequential best-of-3 runs
    moved a type's ratio by up to 1.6x between runs)."""
    from fgcal.estimation.calibrate import CalibrationOptions, calibrate
    from fgcal.io.dataset_io import dataset_model, load_dataset

    loaded = [(ds, dataset_model(ds)) for ds in map(load_dataset, paths)]
    results = [calibrate(ds, model, CalibrationOptions()) for ds, model in loaded]
    best = [np.inf] * len(paths)
    for _ in range(repeat):
        for k, (ds, model) in enumerate(loaded):
            t0 = time.process_time()
            results[k] = calibrate(ds, model, CalibrationOptions())
            best[k] = min(best[k], time.process_time() - t0)
    return best, results


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--rows", type=int, default=3000, help="equations per dataset (about; default 3000)")
    ap.add_argument("--repeat", type=int, default=10,
                    help="interleaved rounds (each calibrates every dataset once), least CPU taken (default 10)")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--data", type=Path, default=None,
                    help="keep the generated datasets here and reuse them on later runs (default: a temporary folder)")
    ap.add_argument("--noise", choices=[*NOISE_CASES, "both"], default="both",
                    help="as-declared: every type's noise is the declared 0.01 mm; misdeclared: three times it "
                         "(each type then estimates its noise and solves again); default both")
    args = ap.parse_args(argv)
    from fgcal.robots.robot_file import load_model

    model = load_model("ur10")
    rng = np.random.default_rng(args.seed)
    x = _truth(model, rng)
    print(f"UR10, about {args.rows} equations a type; CPU s least of {args.repeat} interleaved rounds; single-threaded BLAS")
    print("equations: the measurement rows (the least squares' rows but the priors); per pose: the same CPU over")
    print("the poses (each pose is one forward kinematics and Jacobian a linearisation, whatever its rows; the")
    print("datasets declare joint_resolution 0: the joint readings are exact, not variables with rows of their own)")
    cases = NOISE_CASES if args.noise == "both" else {args.noise: NOISE_CASES[args.noise]}
    with tempfile.TemporaryDirectory() as tmp:
        for case, sigma in cases.items():
            root = (Path(tmp) if args.data is None else args.data) / case
            rows = _datasets(root, model, x, rng, args.rows, sigma)
            print(f"\nnoise {case}: {sigma:g} mm where the datasets declare {SIGMA:g} mm (estimated: noise rounds)")
            print(f"{'type':10s} {'poses':>6s} {'equations':>9s} {'CPU s':>7s} {'us/eq':>7s} {'ratio':>6s} "
                  f"{'us/pose':>8s} {'ratio':>6s}  sigma mm  LM steps  converged")
            ref = ref_pose = None
            cpus, results = cpu_of([root / name for name in rows], args.repeat)
            for (name, n_rows), cpu, result in zip(rows.items(), cpus, results):
                per, per_pose = cpu / n_rows * 1e6, cpu / result.n_poses * 1e6
                ref = per if ref is None else ref
                ref_pose = per_pose if ref_pose is None else ref_pose
                used = next(iter(result.noise.values())).used
                print(f"{name:10s} {result.n_poses:6d} {n_rows:9d} {cpu:7.2f} {per:7.1f} {per / ref:6.2f} "
                      f"{per_pose:8.1f} {per_pose / ref_pose:6.2f}  {used:8.4f}  {result.iterations:8d}  {result.converged}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
