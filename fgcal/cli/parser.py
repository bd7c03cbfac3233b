"""The ``fgcal`` command line's options: one subcommand a job, each option's default the library's
(:func:`fgcal.cli.commands.common.default`), option errors in one line with exit status 2."""
from __future__ import annotations

import argparse
from pathlib import Path

from fgcal._version import __version__
from fgcal.api.calibration import KEEP, MODELS, calibrate
from fgcal.api.compensation import compensate
from fgcal.api.planning import design
from fgcal.api.reporting import report
from fgcal.api.simulation import simulate
from fgcal.api.verification import verify
from fgcal.cli.commands.calibrate import _cmd_calibrate
from fgcal.cli.commands.check import _cmd_check
from fgcal.cli.commands.checks import MAX_POSES
from fgcal.cli.commands.common import default as _d
from fgcal.cli.commands.compensate import _cmd_compensate
from fgcal.cli.commands.demo import _cmd_demo
from fgcal.cli.commands.design import _cmd_design
from fgcal.cli.commands.detect import _cmd_detect
from fgcal.cli.commands.export import _cmd_export
from fgcal.cli.commands.measure import _cmd_measure
from fgcal.cli.commands.online import _cmd_online
from fgcal.cli.commands.options import (
    RenamedOption,
    count,
    nonnegative_deg,
    nonnegative_mm,
    number,
    payload_spec,
    positive,
    positive_deg,
    positive_mm,
    probability,
    scheduler_address,
    seed,
)
from fgcal.cli.commands.report import _cmd_report
from fgcal.cli.commands.simulate import _cmd_simulate, add_setup_options
from fgcal.cli.commands.study import _cmd_study
from fgcal.cli.commands.verify import _cmd_verify

__all__ = ["build_parser"]


class _Parser(argparse.ArgumentParser):
    """Option errors in one line (no usage block), exit status 2."""

    def error(self, message):
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


class _Formatter(argparse.HelpFormatter):
    """Every option's help ends with its default, unless the help already states it."""

    def _get_help_string(self, action):
        text = action.help or ""
        value = action.default
        if ("default" in text or "%(default)" in text or not action.option_strings or value is None
                or value is False or value == argparse.SUPPRESS or isinstance(value, bool)):
            return text
        return f"{text} (default %(default)s)" if text else "(default %(default)s)"


def _finish(parser: argparse.ArgumentParser) -> None:
    """Each subcommand (nested ones too): the defaults in its help, and ``-v`` after the subcommand as well."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for child in action.choices.values():
                child.formatter_class = _Formatter
                if not any("-v" in a.option_strings for a in child._actions):
                    child.add_argument("-v", "--verbose", action="store_true", default=argparse.SUPPRESS,
                                       help="log progress to standard error")
                _finish(child)


def _add_noise_options(p: argparse.ArgumentParser, function, when: str = "") -> None:
    """The simulated noise of the instrument and the joints (``simulate``; ``design`` without a dataset),
    their defaults ``function``'s; ``when`` opens each help text."""
    for flag, kind, text in (("--cmm-sigma", nonnegative_mm, "CMM noise per coordinate, mm"),
                             ("--joint-resolution", nonnegative_deg, "joint readings rounded to this, deg (0 = exact)"),
                             ("--repeatability", nonnegative_deg, "joints land off the readings by N(0, this), deg")):
        p.add_argument(flag, type=kind, default=_d(function, flag[2:].replace("-", "_")), help=when + text)


def build_parser() -> argparse.ArgumentParser:
    p = _Parser(prog="fgcal", description="Calibrate robot arm geometry as a factor graph.")
    p.add_argument("--version", action="version", version=f"fgcal {__version__}")
    p.add_argument("-v", "--verbose", action="store_true", help="log progress to standard error")
    sub = p.add_subparsers(dest="command", required=True)

    s = sub.add_parser("simulate", help="the paper's POSE program: simulate a measured robot (writes a dataset)")
    s.add_argument("out", type=Path, help="dataset directory to write")
    s.add_argument("--robot", default=_d(simulate, "robot"),
                   help="built-in model name, model file or URDF file (default puma560)")
    s.add_argument("--chain", default=_d(simulate, "chain"), metavar="BASE,TIP",
                   help="URDF link names of the chain's base and tip (when the URDF has several leaves)")
    s.add_argument("--reflector", default=_d(simulate, "reflector"), metavar="X,Y,Z",
                   help="measure one tracker reflector at X,Y,Z (mm, tool frame) instead of the model's tooling "
                        "balls (levels default to centres)")
    s.add_argument("--poses", type=count(1, MAX_POSES), default=_d(simulate, "poses"),
                   help="number of poses (random plan; default 21)")
    s.add_argument("--seed", type=seed, default=_d(simulate, "seed"), help="random seed")
    s.add_argument("--plan", choices=("random", "paper"), default=_d(simulate, "plan"),
                   help="random reachable joint sets, or the paper's 48-pose experiment")
    _add_noise_options(s, simulate)
    s.add_argument("--outliers", type=probability(), default=_d(simulate, "outliers"),
                   help="fraction of probe points with a gross error")
    s.add_argument("--outlier-size", type=nonnegative_mm, default=_d(simulate, "outlier_size"),
                   help="size of a gross error, mm")
    s.add_argument("--balls", type=count(1, 1000), default=_d(simulate, "balls"),
                   help="balls measured per pose (default 3, or all the tool has if fewer)")
    s.add_argument("--probes-per-ball", type=count(1, 1000), default=_d(simulate, "probes_per_ball"),
                   help="probe points per ball")
    s.add_argument("--levels", default=_d(simulate, "levels"),
                   help="comma-separated files to write: probes, centres, poses (default probes; centres with "
                        "--reflector)")
    s.add_argument("--length-sigma", type=nonnegative_mm, default=_d(simulate, "length_sigma"),
                   help="link length deviations, mm")
    s.add_argument("--angle-sigma", type=nonnegative_deg, default=_d(simulate, "angle_sigma"),
                   help="link angle deviations, deg")
    s.add_argument("--base-length-sigma", type=nonnegative_mm, default=_d(simulate, "base_length_sigma"),
                   help="base placement deviation, mm")
    s.add_argument("--base-angle-sigma", type=nonnegative_deg, default=_d(simulate, "base_angle_sigma"),
                   help="base angle deviation, deg")
    s.add_argument("--truth", type=Path, default=_d(simulate, "truth"),
                   help="truth.yaml of another simulated dataset: the same actual robot (a verification set)")
    s.add_argument("--force", action="store_true", help="replace OUT if it exists")
    add_setup_options(s)
    s.set_defaults(func=_cmd_simulate)

    c = sub.add_parser("check", help="validate a dataset and report what its poses can identify")
    c.add_argument("dataset", type=Path, help="dataset directory (dataset.yaml, joints.csv, ...)")
    c.set_defaults(func=_cmd_check)

    m = sub.add_parser("measure", help="probe points -> ball centres -> poses, with quality checks (two-stage)")
    m.add_argument("dataset", type=Path, help="dataset directory with probes.csv")
    m.add_argument("--out", type=Path, default=None,
                   help="dataset directory to write (default: DATASET-measured beside DATASET)")
    m.add_argument("--method", choices=("svd", "paper"), default="svd",
                   help="least-squares rigid fit of the good balls, or the paper's T = P' P^-1 (default svd)")
    m.add_argument("--free-radius", action="store_true", help="fit each ball's radius too")
    m.add_argument("--threshold", type=positive_mm, default=None,
                   help="RMS sphere-fit residual (mm) that flags a ball; default from the CMM noise")
    m.add_argument("--orthogonality-tolerance", dest="tolerance", type=positive(), default=None,
                   help="with --method paper: the largest error of the rotation's columns (their length, "
                        "n = o x a, o = a x n: eqs. 19-21), unitless; default 10 x the centres' noise over the "
                        "balls' spacing")
    m.add_argument("--tolerance", dest="tolerance", type=positive(), action=RenamedOption,
                   new="--orthogonality-tolerance (unitless; report's --tolerance is in mm)")
    m.add_argument("--show", type=count(0), default=10, help="flagged rows to print (default 10)")
    m.add_argument("--force", action="store_true", help="replace OUT if it exists")
    m.set_defaults(func=_cmd_measure)

    k = sub.add_parser("calibrate", help="batch factor-graph calibration (the paper's ID6); writes fgcal-result/1")
    k.add_argument("dataset", type=Path, nargs="+",
                   help="dataset directory; several: one robot measured in several sessions or from several "
                        "stations, each dataset a station named after its directory (the first is the world)")
    k.add_argument("--out", type=Path, required=True, help="result file (JSON, fgcal-result/1)")
    k.add_argument("--force", action="store_true", help="replace OUT if it exists")
    k.add_argument("--select", dest="poses", default=_d(calibrate, "poses"),
                   help="poses to use: odd, even, first:N, last:N or ranges like 1-21 (default: all)")
    k.add_argument("--poses", dest="poses", action=RenamedOption,
                   new="--select (a selection; --poses is a count in simulate, design and study)")
    k.add_argument("--levels", default=_d(calibrate, "levels"),
                   help="comma-separated levels to use (default: all present)")
    k.add_argument("--robust", choices=("huber", "cauchy"), default=_d(calibrate, "robust"),
                   help="robust loss on the measurements (default: none)")
    k.add_argument("--engine", choices=("batch", "gtsam"), default=_d(calibrate, "engine"),
                   help="batch: fgcal's batched Levenberg-Marquardt; gtsam: GTSAM's own optimiser on the "
                        "same factor graph (slower, same result)")
    k.add_argument("--prior", choices=("none", "weak"), default=_d(calibrate, "prior"),
                   help="weak: 10x the typical deviation on every parameter")
    k.add_argument("--noise", choices=("estimated", "declared"), default=_d(calibrate, "noise"),
                   help="estimated: each level's noise, joint readings included, from the residuals "
                        "where the redundancy allows; declared: dataset.yaml's values only")
    k.add_argument("--estimate-noise", action="store_const", dest="noise", const="estimated",
                   help="the default now (kept for old scripts)")
    k.add_argument("--outliers", choices=("exclude", "none"), default=_d(calibrate, "outliers"),
                   help="exclude: detect gross errors, exclude and name them; none: keep all")
    k.add_argument("--exact-joints", action="store_true", help="treat the joint readings as exact")
    k.add_argument("--extra", default=_d(calibrate, "extra"),
                   help="extra slots to estimate, e.g. j1.theta (redundancy is reported)")
    k.add_argument("--exclude", default=_d(calibrate, "exclude"), help="parameters to hold at nominal")
    k.add_argument("--model", choices=MODELS, default=_d(calibrate, "model"),
                   help="beyond geometry: gravity compliance of the loaded joints, plus a per-joint error map "
                        "(harmonics, chosen by cross-validation on these poses); the simpler models are scored too")
    k.add_argument("--keep", choices=KEEP, default=_d(calibrate, "keep"),
                   help="with --model: write the model asked for, or the one the comparison recommends")
    k.add_argument("--verification", type=Path, default=None,
                   help="held-out dataset: each model's error there is reported (never used for fitting)")
    k.add_argument("--folds", type=count(2, 1000), default=_d(calibrate, "folds"), help="cross-validation folds")
    k.add_argument("--max-harmonics", type=count(1, 1000), default=_d(calibrate, "max_harmonics"),
                   help="largest number of map harmonics per joint tried by the cross-validation")
    k.add_argument("--seed", type=seed, default=_d(calibrate, "seed"), help="seed of the fold assignment")
    k.add_argument("--fold-order", choices=("random", "blocked"), default=_d(calibrate, "fold_order"),
                   help="folds drawn at random, or as contiguous stretches of the poses in id (time) order, which "
                        "also scores drift over the session")
    k.add_argument("--payload", type=payload_spec, default=None,
                   help="load on the tool for the gravity torques: KG or KG,X,Y,Z (kg; mm in the tool frame)")
    k.set_defaults(func=_cmd_calibrate)

    v = sub.add_parser("verify", help="the paper's VERIFY: errors of a result at the poses of a dataset")
    v.add_argument("result", type=Path, help="result file of fgcal calibrate (fgcal-result/1)")
    v.add_argument("dataset", type=Path, help="dataset directory of the same robot (held-out poses)")
    v.add_argument("--select", dest="poses", default=_d(verify, "poses"),
                   help="poses to use (as calibrate's --select; default: all)")
    v.add_argument("--poses", dest="poses", action=RenamedOption,
                   new="--select (a selection; --poses is a count in simulate, design and study)")
    v.add_argument("--out", type=Path, default=None, help="write verify.json (fgcal-verify/1)")
    v.add_argument("--force", action="store_true", help="replace OUT if it exists")
    v.set_defaults(func=_cmd_verify)

    r = sub.add_parser("report", help="the uncertainty report per parameter: HTML, Markdown and PNG figures")
    r.add_argument("result", type=Path, help="result file of fgcal calibrate (fgcal-result/1)")
    r.add_argument("--verify", type=Path, default=None, help="verify.json from fgcal verify")
    r.add_argument("--out", type=Path, required=True, help="output directory")
    r.add_argument("--tolerance", type=positive_mm, default=_d(report, "tolerance"), metavar="MM",
                   help="position tolerance (mm): pass or fail at the verification poses, so it needs --verify "
                        "(exit status 1 on fail, the report is written either way)")
    r.add_argument("--force", action="store_true", help="replace a report already in OUT")
    r.set_defaults(func=_cmd_report)

    from fgcal.cli.commands.importing import add_import_parser

    add_import_parser(sub)

    c2 = sub.add_parser("compensate", help="joint commands that bring the calibrated robot to target poses")
    c2.add_argument("result", type=Path, help="result file of fgcal calibrate (fgcal-result/1)")
    c2.add_argument("targets", type=Path, help="CSV: pose,x,y,z,qw,qx,qy,qz (mm, unit quaternion) or pose,x,y,z "
                                               "(positions only: the orientation is kept at the seed's), with "
                                               "optional seed joints q1..qn (the commanded joints, deg)")
    c2.add_argument("--out", type=Path, default=None,
                    help="CSV of pose,q1..qn (deg; mm for prismatic joints) of the reachable targets; standard "
                         "output if omitted. The "
                         "unreachable ones are named on standard error and the exit status is 3")
    c2.add_argument("--frame", choices=("instrument", "base"), default=_d(compensate, "frame"),
                    help="frame of the targets: the measuring instrument's (default) or the robot's own base frame "
                         "(a URDF's base link; a DH table's base frame, at the mounting face), placed by the "
                         "calibrated base")
    c2.add_argument("--tcp", default=None, metavar="X,Y,Z[,RX,RY,RZ]",
                    help="the targets are for this TCP, given in the model's tool frame (the flange for the "
                         "built-in robots): mm, and deg as R = Rz(RZ) Ry(RY) Rx(RX)")
    c2.add_argument("--branch", default=None, help="configuration of targets without seed joints (PUMA- and UR-type "
                                                   "arms: closed-form IK of the nominal model), e.g. righty/up/noflip; "
                                                   "default: the one reaching most targets")
    c2.add_argument("--seed-joints", default=None, metavar="Q1,..,QN",
                    help="start of the numerical IK for targets without seed joints (any arm; deg, mm for prismatic "
                         "joints): the nominal model is solved from it, then the calibrated one from that command")
    c2.add_argument("--max-change", type=positive_deg, default=_d(compensate, "max_change"), metavar="DEG",
                    help="refuse a solution moving a joint further than this from its seed, deg")
    c2.add_argument("--force", action="store_true", help="replace OUT if it exists")
    c2.set_defaults(func=_cmd_compensate)

    e = sub.add_parser("export", help="the calibrated model as a robot model file and/or URDF")
    e.add_argument("result", type=Path, help="result file of fgcal calibrate (fgcal-result/1)")
    e.add_argument("--model", type=Path, default=None, help="fgcal-robot/1 YAML file to write")
    e.add_argument("--urdf", type=Path, default=None, help="URDF file to write")
    e.add_argument("--deltas", type=Path, default=None,
                   help="CSV of the identified parameters: name,unit,nominal,estimate,delta,sigma (and held ones)")
    e.add_argument("--force", action="store_true", help="replace the files if they exist")
    e.add_argument("--ur-kinematics", type=Path, default=None, metavar="FILE.yaml",
                   help="a UR's kinematics file, as ur_description reads it (kinematics_params_file): base_link "
                        "(the mounting face) to tool0 reproduce the calibrated chain")
    e.add_argument("--ur-hash", default=None,
                   help="the kinematics file's hash (the driver compares it with the controller's calibration "
                        "checksum, calib_..., and warns when they differ); default fgcal_ and a digest of the values")
    e.set_defaults(func=_cmd_export)

    o = sub.add_parser("online", help="incremental calibration as poses arrive (iSAM2, iterated EKF, UKF)")
    o.add_argument("dataset", type=Path,
                   help="dataset directory (with --stdin: only its dataset.yaml, for robot, tool and noise)")
    o.add_argument("--engine", choices=("isam2", "ekf", "ukf"), default="isam2",
                   help="isam2: GTSAM's incremental smoother over the batch's factors; ekf: iterated extended "
                        "Kalman filter; ukf: filterpy's unscented Kalman filter")
    o.add_argument("--out", type=Path, default=None, help="result file (fgcal-result/1) at the end")
    o.add_argument("--checkpoint", type=Path, default=None,
                   help="state after every pose (default OUT.ENGINE.checkpoint with --out, else "
                        "fgcal-online-DATASET-DIGEST-ENGINE.checkpoint here)")
    o.add_argument("--restart", action="store_true", help="ignore an existing checkpoint and start over")
    o.add_argument("--follow", action="store_true", help="keep reading poses appended to the dataset")
    o.add_argument("--stdin", action="store_true",
                   help="read poses from standard input (DATASET gives robot, tool and noise); "
                        "records: joints,POSE,q1..qn / probe,POSE,BALL,x,y,z / centre,... / pose,... / end,POSE")
    o.add_argument("--interval", type=positive("s", 3600.0), default=1.0, help="seconds between polls with --follow")
    o.add_argument("--plot", type=Path, default=None, help="convergence plot (PNG) at the end")
    o.add_argument("--drift", type=number(0.0, 1000.0, unit="mm, deg"), nargs=2, metavar=("MM", "DEG"), default=None,
                   help="random-walk drift of the parameters per pose for ekf/ukf: MM (mm) for lengths, DEG (deg) for angles "
                        "(default none)")
    o.add_argument("--model", choices=MODELS, default=None,
                   help="follow a drifting robot one pose ahead: the geometry and (compliance, compliance+map) the "
                        "joint-error block as random walks in an iterated EKF; writes fgcal-drift/1 with --out")
    o.add_argument("--harmonics", type=count(1, 1000), default=30, help="with --model compliance+map: map harmonics")
    o.add_argument("--map-sigma", type=positive("urad", 1e5), default=300.0,
                   help="with --model compliance+map: prior of each map coefficient (urad)")
    o.add_argument("--joint-errors", type=Path, default=None,
                   help="with --model: take the joint-error block of this fgcal calibrate --model result")
    o.add_argument("--map-drift", type=number(0.0, 1e4, unit="urad"), default=None,
                   help="with --model: random-walk step per pose of each map coefficient (urad; compliances 0.1 of "
                        "it in urad/Nm); chosen with the geometry's on the training poses when --drift is not given")
    o.add_argument("--train", type=number(0.0, 1.0, low_open=True, high_open=True), default=0.6,
                   help="with --model: share of the poses (the first) the drift and noise are chosen on; the "
                        "one-step-ahead summary is of the rest")
    o.add_argument("--baseline", type=Path, default=None,
                   help="with --model: a batch result whose errors at the same later poses are reported beside")
    o.set_defaults(func=_cmd_online)

    st = sub.add_parser("study", help="simulation studies: the paper's Figs. 8, 9, 13, its experiment, noise sweeps")
    st.add_argument("name", choices=("fig8-9", "fig13", "experiment", "sweep-cmm", "sweep-joint",
                                     "sweep-repeatability", "design"),
                    help="which study: fig8-9, fig13 and experiment as in the paper; sweeps of one noise; design "
                         "(designed against random plans)")
    st.add_argument("--out", type=Path, default=None, help="output directory (default study-NAME); resumes")
    st.add_argument("--trials", type=count(1, 10**6), default=None,
                    help="trials (per point for fig8-9, experiment, sweeps)")
    st.add_argument("--poses", type=count(1, MAX_POSES), default=None, help="observations per calibration (fig13, sweeps)")
    st.add_argument("--seed", type=seed, default=0, help="random seed of the trials")
    st.add_argument("--robot", default="puma560",
                    help="simulated robot of every trial: built-in name, model file or URDF with tooling balls "
                         "(experiment: puma560 only)")
    st.add_argument("--workers", type=count(1, 1024), default=None, help="local processes (default: all cores)")
    st.add_argument("--scheduler", type=scheduler_address, default=None, help="Dask distributed scheduler address, e.g. tcp://host:8786")
    st.set_defaults(func=_cmd_study)

    de = sub.add_parser("design", help="which poses to measure: an optimal plan from a candidate pool")
    de.add_argument("--dataset", type=Path, default=_d(design, "dataset"),
                    help="design for this dataset's robot, tool, measurement type and noise; its poses are the "
                         "candidates unless --candidates FILE")
    de.add_argument("--robot", default=_d(design, "robot"), help="without --dataset: the robot to plan for")
    de.add_argument("--levels", dest="level", choices=("probes", "centres", "poses"), default=_d(design, "level"),
                    help="without --dataset: the level measured at a pose, one of probes, centres, poses "
                         "(default probes on 3 balls)")
    de.add_argument("--level", dest="level", choices=("probes", "centres", "poses"), action=RenamedOption,
                    new="--levels (as simulate and calibrate spell it)")
    de.add_argument("--poses", type=count(1, MAX_POSES), default=_d(design, "poses"), help="number of poses to plan")
    de.add_argument("--per-placement", action="store_true",
                    help="with --dataset of contacts: --poses at each placement (fixtures linked by known "
                         "distances) instead of in all")
    de.add_argument("--candidates", default=_d(design, "candidates"),
                    help="with --dataset: a joints.csv-like file of candidate poses (pose,q1..qn deg); "
                         "without: the number of random reachable candidates (default 2000)")
    de.add_argument("--index", choices=("O1", "O2", "O3", "O4", "O5", "pred"), default=_d(design, "index"),
                    help="criterion: observability index O1-O5, or pred (predicted accuracy; default)")
    de.add_argument("--seed", type=seed, default=_d(design, "seed"), help="random seed of the candidates")
    de.add_argument("--noise", choices=("estimated", "declared"), default=_d(design, "noise"),
                    help="with --dataset: design for the noise a calibration of it estimates (default) or its "
                         "declared noise")
    _add_noise_options(de, design, "without --dataset: ")
    de.add_argument("--out", type=Path, required=True, help="plan CSV: pose,q1..qn (deg); the candidates' pose ids")
    de.add_argument("--force", action="store_true", help="replace OUT if it exists")
    de.set_defaults(func=_cmd_design)

    dt = sub.add_parser("detect", help="chessboard corners in images -> pixels.csv (OpenCV: pip install fgcal[camera])")
    dt.add_argument("images", type=Path, nargs="+", help="image files; each one's pose id is the last number in its "
                                                           "name (img_012.png: 12), else its place in the list")
    dt.add_argument("--grid", required=True, help="the board's inner corners ROWSxCOLS (points r{i}c{j})")
    dt.add_argument("--square", required=True, type=positive_mm,
                    help="the board's square (mm), for the targets: entry printed")
    dt.add_argument("--camera", default="left", help="the camera's name in pixels.csv (default left)")
    dt.add_argument("--out", type=Path, required=True, help="pixels.csv to write (pose,camera,point,u,v)")
    dt.set_defaults(func=_cmd_detect)

    d = sub.add_parser("demo", help="run the main job on the bundled dataset")
    d.add_argument("--out", type=Path, default=None,
                   help="output directory (default: a new folder in the system's temporary directory)")
    d.add_argument("--force", action="store_true", help="replace the demo's files already in OUT")
    d.set_defaults(func=_cmd_demo)
    _finish(p)
    return p
