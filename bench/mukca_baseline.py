#!/usr/bin/env python3
"""MUKCa baseline: the authors' two-socket calibration, reimplemented standalone.

What the method is
------------------
MUKCa (Franzese, Spahn, Kober, Della Santina, "MUKCa: Accurate and Affordable
Cobot Calibration Without External Measurement Devices", arXiv:2503.12584)
calibrates a serial arm from joint readings alone.  A plate with two spherical
sockets a known distance apart (50 mm) is placed in front of the robot; a ball
on the flange is seated in socket 0 and then socket 1 in many arm
configurations.  The calibration changes the URDF's joint <origin> elements
(xyz and rpy, six numbers per joint) so that

  * consistency: for every socket, the ball centres predicted by forward
    kinematics gather at one point (their spread about their own mean, the
    mean being recomputed from the current parameters, is minimised), and
  * distortion: the distance between the two socket means equals 50 mm,

with a small Tikhonov pull of the parameters towards the nominal URDF.

Source read
-----------
github.com/platonics-delft/kinematics_calibration, commit
05a05ab4cbbe328c8f5bfcc76479c752ed07b82e (the same commit the data in
/work/shared/data/mukca-panda were copied from).  Files read:
calibrate_fk/parameter_optimizer.py (objective, regulariser, solver),
calibrate_fk/utils.py (data reading, outlier step, evaluation metrics),
config_optimizer/panda.yaml (which joints), scripts/run_optimizer.py,
scripts/comparison_with_sota.py, scripts/statistical_analysis_one_to_many.py,
scripts/statistical_analysis_many_to_one.py (how the pieces are called) and
README.md.  No code of theirs is copied here; this is a reimplementation.

Their method as found in that code (SI units: metres, radians)
--------------------------------------------------------------
* Parameters: xyz + rpy of the <origin> of panda_joint1 ... panda_joint7 and
  ball_joint (config_optimizer/panda.yaml): 8 x 6 = 48 numbers.  The fixed
  joints panda_joint8, panda_hand_joint and panda_hand_tcp_joint are NOT
  optimised ("We are not optimizing the transformation from joint_7 to end
  effector"); ball_joint (panda_hand_tcp -> ball_link) is.  Joint offsets,
  axes and the socket positions are not parameters (the socket positions are
  eliminated by the per-socket means).  Start point: the nominal URDF values.
* Objective, summed over training placements p:
      (N0 * var0 + N1 * var1) / (N0 + N1)          [consistency, m^2]
    + (|mean0 - mean1| - 0.05)^2                   [distortion, m^2]
  where var_k = sum over x,y,z of the population variance of socket k's
  predicted ball centres (= mean squared distance from their mean); both terms
  weight 1.  Plus the regulariser
      n_placements * 1e-4 * sum (theta - theta_nominal)^2
  over all optimised numbers EXCEPT those of ball_joint (metres and radians
  mixed, unweighted).  (ParameterOptimizer.optimize() defaults: dynamic means,
  distortion term and regulariser all on; regulariser weight 1e-4 and
  distance 0.05 m are the defaults of every script.)
* Optimiser: CasADi nlpsol 'ipopt', unconstrained, exact derivatives from
  CasADi's symbolic FK, options {'print_level': 0, 'max_iter': 30}, x0 =
  nominal.
* Outliers: utils.remove_outliers computes an IQR mask (alpha = 2) but the line
  applying it is commented out, so all recorded configurations are used.
* Evaluation (utils.evaluate_model): per placement, the socket means, the
  pooled RMS spread sqrt((N0 var0 + N1 var1)/(N0+N1)) ("std_dev_fk",
  consistency) and | |mean0 - mean1| - 0.05 | (distortion).

What differs here
-----------------
* The objective, parameters, regulariser and weights are the same.  The
  optimiser is not IPOPT: the objective is a plain sum of squares, so it is
  written as residuals and solved by scipy.optimize.least_squares (trust-region
  reflective, analytic Jacobian) to convergence from the nominal values.
  Checked against CasADi 3.6.7 + IPOPT with their options on the same
  objective (a separate script outside this repository; the authors' own code
  needs forwardkinematics from a git branch, ft-symbolic-fk, that is not on
  PyPI, so it was not run): IPOPT stops after 6 (one placement) and 10 (three
  placements) iterations at its default tol 1e-8 on the gradient, objective
  equal to 1e-6 relative; parameters agree within 8e-5 (m or rad; the
  remainder lies along directions held only by the 1e-4 regulariser) and the
  held-out figures below agree within 0.002 mm.
* The roll/pitch/yaw of ball_joint cannot move ball_link's origin (zero
  gradient, and the regulariser skips ball_joint), so IPOPT leaves them at
  nominal; here they are held at nominal instead of being free.
* Forward kinematics are this file's own (URDF rpy = Rz(yaw) Ry(pitch)
  Rx(roll), the convention of the authors' FK package).
* Note: the repository's scripts/run_optimizer.py at that commit calls
  optimize(use_dynamic_means=True, use_distortion_error=False,
  use_regularization=False), i.e. variance only; the paper's method, the
  optimize() defaults, their statistical-analysis scripts and the full row of
  their ablation (scripts/comparison_with_sota.py) use all three terms.  The
  default here is the full method.  `--variant variance-only` gives
  run_optimizer.py's objective, which is degenerate: shrinking the links
  moves every centre to one point, so its minimum has zero spread and a
  0 mm socket distance (converged here: |distance error| 50 mm; IPOPT
  stopped by max_iter 30 is part way there, 29-33 mm).  Not a baseline.
* Reported metrics here are per socket (RMS and max distance of the predicted
  centres from their mean) and the signed distance error, in mm; the authors'
  pooled figure (std_dev_fk) is reported too, as pooled_rms_mm.

Results (data as shipped, sorted placement order, full variant)
----------------------------------------------------------------
  held-out means            consistency RMS mm    |distance error| mm
                            nominal   MUKCa        nominal   MUKCa
  train1 (back_left)         8.967    1.148         1.718    0.347
  train3 (first three)       8.961    0.490         1.348    0.159
  all-single (9 runs avg)    8.385    0.701         1.585    0.259

Usage
-----
  python bench/mukca_baseline.py [--data DIR] [--train a,b,c] [--all-single]
                                 [--variant full|variance-only] [--out r.json]

Importable by path: calibrate_mukca(train_sets, urdf_path) -> params and
evaluate(params, sets) -> dict; load_sets(data_dir) reads the placements.
Standalone: numpy and scipy only.
"""
import argparse
import json
import os
import sys
import time

import numpy as np
from scipy.optimize import least_squares

OPTIMISED_JOINTS = [f"panda_joint{i}" for i in range(1, 8)] + ["ball_joint"]
UNREGULARISED_JOINTS = ("ball_joint",)
REG_WEIGHT = 1e-4          # per training placement
PARAM_NAMES = ("x", "y", "z", "roll", "pitch", "yaw")


# The chain and its kinematics, the placements and their scores: modules beside this file, loaded by
# path (this file is run as a script and loaded by path itself: its folder need not be on sys.path).
def _sibling(name):
    import importlib.util

    spec = importlib.util.spec_from_file_location(name, os.path.join(os.path.dirname(os.path.abspath(__file__)),
                                                                     f"{name}.py"))
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


_kinematics, _placements = _sibling("mukca_kinematics"), _sibling("mukca_placements")
parse_chain, nominal_params, fk, write_urdf = (_kinematics.parse_chain, _kinematics.nominal_params, _kinematics.fk,
                                               _kinematics.write_urdf)
DEFAULT_DATA, SOCKET_DISTANCE = _placements.DEFAULT_DATA, _placements.SOCKET_DISTANCE
load_sets, _as_list, summarise = _placements.load_sets, _placements._as_list, _placements.summarise


def evaluate(params, sets):
    """Per placement: per-socket consistency and the distance error, in mm (``mukca_placements.scores``).

    params: from calibrate_mukca() or nominal_params(), or a URDF path (nominal).
    """
    if isinstance(params, str):
        params = nominal_params(params)
    return _placements.scores(lambda Q: fk(params, Q), sets)


# -------------------------------------------------------------- calibration
def _vector(params, joints):
    return np.concatenate([np.asarray(params["origins"][j], float) for j in joints])


def _with_vector(params, joints, x):
    new = dict(params)
    new["origins"] = {k: list(v) for k, v in params["origins"].items()}
    for k, j in enumerate(joints):
        new["origins"][j] = [float(v) for v in x[6 * k:6 * k + 6]]
    return new


def mukca_objective_terms(params, sets, joints=OPTIMISED_JOINTS, x0=None,
                          distortion=True, regularise=True, jacobian=False):
    """Residual vector r (objective = r.r, exactly the authors' sum) and optionally dr/dx."""
    sets = _as_list(sets)
    res, jac = [], []
    for _, (Q0, Q1) in sets:
        n_tot = len(Q0) + len(Q1)
        means, mjac = [], []
        for Q in (Q0, Q1):
            P, J = fk(params, Q, joints)
            m, Jm = P.mean(0), J.mean(0)
            res.append(((P - m) / np.sqrt(n_tot)).ravel())
            jac.append(((J - Jm) / np.sqrt(n_tot)).reshape(-1, J.shape[2]))
            means.append(m)
            mjac.append(Jm)
        if distortion:
            d = means[0] - means[1]
            dn = np.linalg.norm(d)
            res.append(np.array([dn - SOCKET_DISTANCE]))
            jac.append(((d / dn) @ (mjac[0] - mjac[1]))[None, :])
    if regularise:
        w = np.sqrt(len(sets) * REG_WEIGHT)
        x = _vector(params, joints)
        mask = np.concatenate([np.full(6, j not in UNREGULARISED_JOINTS, float) for j in joints])
        sel = mask > 0
        res.append(w * (x - x0)[sel])
        jac.append((w * np.eye(len(x)))[sel])
    r = np.concatenate(res)
    return (r, np.vstack(jac)) if jacobian else r


def calibrate_mukca(train_sets, urdf_path, variant="full", verbose=False):
    """The authors' calibration on train_sets ({name: (Q0, Q1)} or a list of pairs).

    Returns a params dict (JSON-serialisable) for evaluate()/fk().
    variant: "full" (consistency + distortion + regulariser: the MUKCa method)
    or "variance-only" (run_optimizer.py's setting at the commit read).
    """
    if variant not in ("full", "variance-only"):
        raise ValueError(variant)
    nominal = nominal_params(urdf_path)
    joints = [j for j in OPTIMISED_JOINTS if j in nominal["origins"]]
    x0 = _vector(nominal, joints)
    full = variant == "full"
    # The rpy of the joint into the tip link cannot move the tip's origin (the
    # ball centre): zero gradient, and no regulariser on ball_joint, so IPOPT
    # leaves them at nominal; they are held there rather than left free.
    free = np.ones(len(x0), bool)
    if joints[-1] == nominal["chain"][-1]["name"]:
        free[-3:] = False

    def fun(z):
        x = x0.copy()
        x[free] = z
        r, J = mukca_objective_terms(_with_vector(nominal, joints, x), train_sets, joints,
                                     x0, distortion=full, regularise=full, jacobian=True)
        return r, J[:, free]

    cache = {}

    def residuals(x):
        key = x.tobytes()
        if key not in cache:
            cache.clear()
            cache[key] = fun(x)
        return cache[key][0]

    def jacobian(x):
        residuals(x)
        return cache[x.tobytes()][1]

    t0 = time.time()
    sol = least_squares(residuals, x0[free], jac=jacobian, method="trf", x_scale=1.0,
                        ftol=1e-15, xtol=1e-15, gtol=1e-15, max_nfev=500)
    x = x0.copy()
    x[free] = sol.x
    out = _with_vector(nominal, joints, x)
    out["optimised"] = joints
    out["variant"] = variant
    out["train"] = [name for name, _ in _as_list(train_sets)]
    out["solver"] = {"method": "scipy least_squares trf", "nfev": int(sol.nfev),
                     "status": int(sol.status), "cost": float(2 * sol.cost),
                     "cost_nominal": float(residuals(x0[free]) @ residuals(x0[free])),
                     "grad_inf": float(np.abs(2 * jacobian(sol.x).T @ residuals(sol.x)).max()),
                     "seconds": round(time.time() - t0, 3)}
    if verbose:
        print(f"  calibrated on {out['train']}: objective {out['solver']['cost_nominal']:.4e}"
              f" -> {out['solver']['cost']:.4e} m^2 in {sol.nfev} evaluations", file=sys.stderr)
    return out


# ---------------------------------------------------------------------- CLI
def run_protocol(urdf, sets, train_names, variant, verbose=True):
    train = {k: sets[k] for k in train_names}
    test = {k: v for k, v in sets.items() if k not in train_names}
    nominal = nominal_params(urdf)
    calibrated = calibrate_mukca(train, urdf, variant=variant, verbose=verbose)
    res = {"train": list(train_names), "test": list(test),
           "nominal": {"per_placement": evaluate(nominal, test)},
           "calibrated": {"per_placement": evaluate(calibrated, test)},
           "calibrated_on_train": {"per_placement": evaluate(calibrated, train)},
           "solver": calibrated["solver"],
           "params": {j: calibrated["origins"][j] for j in calibrated["optimised"]},
           "param_change": {j: [a - b for a, b in zip(calibrated["origins"][j], nominal["origins"][j])]
                            for j in calibrated["optimised"]}}
    for key in ("nominal", "calibrated", "calibrated_on_train"):
        res[key]["mean"] = summarise(res[key]["per_placement"])
    return res


def print_protocol(label, res):
    print(f"\n== {label}: trained on {', '.join(res['train'])}; held out {len(res['test'])}")
    print(f"{'placement':<14}{'model':<11}{'s0 rms':>8}{'s0 max':>8}{'s1 rms':>8}{'s1 max':>8}"
          f"{'dist err':>10}   (mm)")
    for name in res["test"]:
        for key in ("nominal", "calibrated"):
            r = res[key]["per_placement"][name]
            s0, s1 = r["socket"]
            print(f"{name:<14}{key:<11}{s0['rms_mm']:8.3f}{s0['max_mm']:8.3f}"
                  f"{s1['rms_mm']:8.3f}{s1['max_mm']:8.3f}{r['distance_error_mm']:10.3f}")
    for key in ("nominal", "calibrated", "calibrated_on_train"):
        m = res[key]["mean"]
        print(f"mean {key:<20} consistency rms {m['consistency_rms_mm']:.3f}  "
              f"max {m['consistency_max_mm']:.3f}  |dist err| {m['abs_distance_error_mm']:.3f} mm")


def _average_runs(runs):
    out = {}
    for key in ("nominal", "calibrated", "calibrated_on_train"):
        ms = [r[key]["mean"] for r in runs]
        out[key] = {k: float(np.mean([m[k] for m in ms])) for k in ms[0] if k != "n_placements"}
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--data", default=DEFAULT_DATA)
    ap.add_argument("--train", help="comma-separated placements to train on (one protocol)")
    ap.add_argument("--all-single", action="store_true",
                    help="also train on each placement in turn and average the held-out results")
    ap.add_argument("--variant", choices=("full", "variance-only"), default="full")
    ap.add_argument("--out", help="write the results as JSON here")
    ap.add_argument("--urdf-out", help="directory: write each calibrated URDF there")
    args = ap.parse_args(argv)

    urdf = os.path.join(args.data, "panda.urdf")
    sets = load_sets(args.data)
    names = list(sets)
    if args.train:
        protocols = {"custom": [t.strip() for t in args.train.split(",") if t.strip()]}
        unknown = [t for t in protocols["custom"] if t not in sets]
        if unknown:
            ap.error(f"unknown placements {unknown}; have {names}")
    else:
        protocols = {"train1": names[:1], "train3": names[:3]}

    t0 = time.time()
    result = {"method": "MUKCa (platonics-delft/kinematics_calibration @ 05a05ab), reimplemented",
              "variant": args.variant, "data": os.path.abspath(args.data),
              "placements": names, "protocols": {}}
    for label, train in protocols.items():
        res = run_protocol(urdf, sets, train, args.variant)
        result["protocols"][label] = res
        print_protocol(label, res)
        if args.urdf_out:
            os.makedirs(args.urdf_out, exist_ok=True)
            p = nominal_params(urdf)
            p["origins"].update(res["params"])
            p["optimised"] = list(res["params"])
            write_urdf(p, os.path.join(args.urdf_out, f"panda_{label}.urdf"))
    if args.all_single:
        runs = [run_protocol(urdf, sets, [n], args.variant, verbose=False) for n in names]
        avg = _average_runs(runs)
        result["all_single"] = {"runs": {r["train"][0]: {k: r[k] for k in
                                                          ("nominal", "calibrated", "calibrated_on_train", "solver")}
                                         for r in runs},
                                "mean": avg}
        print(f"\n== all-single: trained on each of {len(names)} placements in turn, "
              f"held-out means averaged over the runs")
        print(f"{'trained on':<14}{'nominal rms':>12}{'calib rms':>11}{'nominal |de|':>14}{'calib |de|':>12}   (mm)")
        for r in runs:
            a, b = r["nominal"]["mean"], r["calibrated"]["mean"]
            print(f"{r['train'][0]:<14}{a['consistency_rms_mm']:12.3f}{b['consistency_rms_mm']:11.3f}"
                  f"{a['abs_distance_error_mm']:14.3f}{b['abs_distance_error_mm']:12.3f}")
        print(f"{'average':<14}{avg['nominal']['consistency_rms_mm']:12.3f}"
              f"{avg['calibrated']['consistency_rms_mm']:11.3f}"
              f"{avg['nominal']['abs_distance_error_mm']:14.3f}{avg['calibrated']['abs_distance_error_mm']:12.3f}")
    result["seconds"] = round(time.time() - t0, 2)
    print(f"\n({result['seconds']} s)")
    if args.out:
        with open(args.out, "w") as f:
            json.dump(result, f, indent=1)
    return result


if __name__ == "__main__":
    main()
