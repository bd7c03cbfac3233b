"""The ``fgcal`` command line: a thin layer over the library.

A user's mistake (a bad file, an impossible option) ends in one line on standard error and
exit status 2, with no traceback.
"""
from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path

from fgcal._version import __version__
from fgcal.cli.commands.calibrate import _cmd_calibrate
from fgcal.cli.commands.check import _cmd_check
from fgcal.cli.commands.checks import (
    finite_float,
    nonnegative_float,
    nonnegative_int,
    os_error_message,
    positive_float,
    positive_int,
)
from fgcal.cli.commands.compensate import _cmd_compensate
from fgcal.cli.commands.demo import _cmd_demo
from fgcal.cli.commands.design import _cmd_design
from fgcal.cli.commands.export import _cmd_export
from fgcal.cli.commands.measure import _cmd_measure
from fgcal.cli.commands.online import _cmd_online
from fgcal.cli.commands.report import _cmd_report
from fgcal.cli.commands.simulate import _cmd_simulate, add_setup_options
from fgcal.cli.commands.study import _cmd_study
from fgcal.cli.commands.verify import _cmd_verify
from fgcal.errors import FgcalError

log = logging.getLogger("fgcal")


class _Parser(argparse.ArgumentParser):
    """Option errors in one line (no usage block), exit status 2."""

    def error(self, message):
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def build_parser() -> argparse.ArgumentParser:
    p = _Parser(prog="fgcal", description="Calibrate robot arm geometry as a factor graph.")
    p.add_argument("--version", action="version", version=f"fgcal {__version__}")
    p.add_argument("-v", "--verbose", action="store_true", help="log progress to standard error")
    sub = p.add_subparsers(dest="command", required=True)

    s = sub.add_parser("simulate", help="the paper's POSE program: simulate a measured robot (writes a dataset)")
    s.add_argument("out", type=Path, help="dataset directory to write")
    s.add_argument("--robot", default="puma560",
                   help="built-in model name, model file or URDF file (default puma560)")
    s.add_argument("--chain", default=None, metavar="BASE,TIP",
                   help="URDF link names of the chain's base and tip (when the URDF has several leaves)")
    s.add_argument("--reflector", default=None, metavar="X,Y,Z",
                   help="measure one tracker reflector at X,Y,Z (mm, tool frame) instead of the model's tooling "
                        "balls (levels default to centres)")
    s.add_argument("--poses", type=positive_int, default=None, help="number of poses (random plan; default 21)")
    s.add_argument("--seed", type=nonnegative_int, default=0, help="random seed (default 0)")
    s.add_argument("--plan", choices=("random", "paper"), default="random",
                   help="random reachable joint sets, or the paper's 48-pose experiment")
    s.add_argument("--cmm-sigma", type=nonnegative_float, default=0.01, help="CMM noise per coordinate, mm (default 0.01)")
    s.add_argument("--joint-resolution", type=nonnegative_float, default=0.01,
                   help="joint readings rounded to this, deg (default 0.01; 0 = exact)")
    s.add_argument("--repeatability", type=nonnegative_float, default=0.0,
                   help="joints land off the readings by N(0, this) deg (default 0)")
    s.add_argument("--outliers", type=finite_float, default=0.0, help="fraction of probe points with a gross error")
    s.add_argument("--outlier-size", type=nonnegative_float, default=0.5, help="size of a gross error, mm (default 0.5)")
    s.add_argument("--balls", type=positive_int, default=None,
                   help="balls measured per pose (default 3, or all the tool has if fewer)")
    s.add_argument("--probes-per-ball", type=positive_int, default=4, help="probe points per ball (default 4)")
    s.add_argument("--levels", default=None,
                   help="comma-separated files to write: probes, centres, poses (default probes; centres with "
                        "--reflector)")
    s.add_argument("--length-sigma", type=nonnegative_float, default=0.5,
                   help="link length deviations, mm (default 0.5)")
    s.add_argument("--angle-sigma", type=nonnegative_float, default=0.05,
                   help="link angle deviations, deg (default 0.05)")
    s.add_argument("--base-length-sigma", type=nonnegative_float, default=5.0,
                   help="base placement deviation, mm (default 5)")
    s.add_argument("--base-angle-sigma", type=nonnegative_float, default=0.5,
                   help="base angle deviation, deg (default 0.5)")
    s.add_argument("--truth", type=Path, default=None,
                   help="truth.yaml of another simulated dataset: the same actual robot (a verification set)")
    s.add_argument("--force", action="store_true", help="replace OUT if it exists")
    add_setup_options(s)
    s.set_defaults(func=_cmd_simulate)

    c = sub.add_parser("check", help="validate a dataset and report what its poses can identify")
    c.add_argument("dataset", type=Path)
    c.set_defaults(func=_cmd_check)

    m = sub.add_parser("measure", help="probe points -> ball centres -> poses, with quality checks (two-stage)")
    m.add_argument("dataset", type=Path)
    m.add_argument("--out", type=Path, default=None,
                   help="dataset directory to write (default: DATASET-measured beside DATASET)")
    m.add_argument("--method", choices=("svd", "paper"), default="svd",
                   help="least-squares rigid fit of the good balls, or the paper's T = P' P^-1 (default svd)")
    m.add_argument("--free-radius", action="store_true", help="fit each ball's radius too")
    m.add_argument("--threshold", type=positive_float, default=None,
                   help="RMS sphere-fit residual (mm) that flags a ball; default from the CMM noise")
    m.add_argument("--tolerance", type=positive_float, default=None, help="eqs. 19-21 tolerance for --method paper")
    m.add_argument("--show", type=nonnegative_int, default=10, help="flagged rows to print (default 10)")
    m.add_argument("--force", action="store_true", help="replace OUT if it exists")
    m.set_defaults(func=_cmd_measure)

    k = sub.add_parser("calibrate", help="batch factor-graph calibration (the paper's ID6); writes fgcal-result/1")
    k.add_argument("dataset", type=Path, nargs="+",
                   help="dataset directory; several: one robot measured in several sessions or from several "
                        "stations, each dataset a station named after its directory (the first is the world)")
    k.add_argument("--out", type=Path, required=True, help="result file (JSON)")
    k.add_argument("--poses", default=None, help="poses to use: odd, even, first:N, last:N or ranges like 1-21")
    k.add_argument("--levels", default=None, help="comma-separated levels to use (default: all present)")
    k.add_argument("--robust", choices=("huber", "cauchy"), default=None, help="robust loss on the measurements")
    k.add_argument("--engine", choices=("batch", "gtsam"), default="batch",
                   help="batch: fgcal's batched Levenberg-Marquardt (default); gtsam: GTSAM's own optimiser on the "
                        "same factor graph (slower, same result)")
    k.add_argument("--prior", choices=("none", "weak"), default="none",
                   help="weak: 10x the typical deviation on every parameter (default none)")
    k.add_argument("--noise", choices=("estimated", "declared"), default="estimated",
                   help="estimated (default): each level's noise, joint readings included, from the residuals "
                        "where the redundancy allows; declared: dataset.yaml's values only")
    k.add_argument("--estimate-noise", action="store_const", dest="noise", const="estimated",
                   help="the default now (kept for old scripts)")
    k.add_argument("--outliers", choices=("exclude", "none"), default="exclude",
                   help="exclude (default): detect gross errors, exclude and name them; none: keep all")
    k.add_argument("--exact-joints", action="store_true", help="treat the joint readings as exact")
    k.add_argument("--extra", default=None, help="extra slots to estimate, e.g. j1.theta (redundancy is reported)")
    k.add_argument("--exclude", default=None, help="parameters to hold at nominal")
    k.add_argument("--model", choices=("geometric", "compliance", "compliance+map"), default="geometric",
                   help="beyond geometry: gravity compliance of the loaded joints, plus a per-joint error map "
                        "(harmonics, chosen by cross-validation on these poses); the simpler models are scored too")
    k.add_argument("--verification", type=Path, default=None,
                   help="held-out dataset: each model's error there is reported (never used for fitting)")
    k.add_argument("--folds", type=int, default=5, help="cross-validation folds (default 5)")
    k.add_argument("--max-harmonics", type=int, default=30,
                   help="largest number of map harmonics per joint tried by the cross-validation (default 30)")
    k.add_argument("--seed", type=int, default=0, help="seed of the fold assignment (default 0)")
    k.add_argument("--fold-order", choices=("random", "blocked"), default="random",
                   help="folds drawn at random, or as contiguous stretches of the poses in id (time) order, which "
                        "also scores drift over the session (default random)")
    k.add_argument("--payload", default=None, help="load on the tool for the gravity torques: KG or KG,X,Y,Z (mm)")
    k.set_defaults(func=_cmd_calibrate)

    v = sub.add_parser("verify", help="the paper's VERIFY: errors of a result at the poses of a dataset")
    v.add_argument("result", type=Path)
    v.add_argument("dataset", type=Path)
    v.add_argument("--poses", default=None, help="poses to use (as for calibrate)")
    v.add_argument("--out", type=Path, default=None, help="write verify.json")
    v.set_defaults(func=_cmd_verify)

    r = sub.add_parser("report", help="the uncertainty report per parameter: HTML, Markdown and PNG figures")
    r.add_argument("result", type=Path)
    r.add_argument("--verify", type=Path, default=None, help="verify.json from fgcal verify")
    r.add_argument("--out", type=Path, required=True, help="output directory")
    r.add_argument("--tolerance", type=float, default=None, metavar="MM",
                   help="position tolerance (mm): pass or fail at the verification poses "
                        "(exit status 1 on fail, the report is written either way)")
    r.set_defaults(func=_cmd_report)

    from fgcal.cli.commands.importing import add_import_parser

    add_import_parser(sub)

    c2 = sub.add_parser("compensate", help="joint commands that bring the calibrated robot to target poses")
    c2.add_argument("result", type=Path)
    c2.add_argument("targets", type=Path, help="CSV: pose,x,y,z,qw,qx,qy,qz[,q1..q6 seed joints in deg]")
    c2.add_argument("--out", type=Path, default=None,
                    help="CSV of pose,q1..q6 (deg) of the reachable targets; standard output if omitted. The "
                         "unreachable ones are named on standard error and the exit status is 3")
    c2.add_argument("--frame", choices=("instrument", "base"), default="instrument",
                    help="frame of the targets: the measuring instrument's (default) or the robot's own base frame "
                         "(a URDF's base link; a DH table's base frame, at the mounting face), placed by the "
                         "calibrated base")
    c2.add_argument("--tcp", default=None, metavar="X,Y,Z[,RX,RY,RZ]",
                    help="the targets are for this TCP, given in the model's tool frame (the flange for the "
                         "built-in robots): mm, and deg as R = Rz(RZ) Ry(RY) Rx(RX)")
    c2.add_argument("--branch", default=None, help="configuration of targets without seed joints (PUMA-type arms), "
                                                   "e.g. righty/up/noflip; default: the one reaching most targets")
    c2.add_argument("--max-change", type=float, default=10.0, metavar="DEG",
                    help="refuse a solution moving a joint further than this from its seed (default 10)")
    c2.set_defaults(func=_cmd_compensate)

    e = sub.add_parser("export", help="the calibrated model as a robot model file and/or URDF")
    e.add_argument("result", type=Path)
    e.add_argument("--model", type=Path, default=None, help="fgcal-robot/1 YAML file to write")
    e.add_argument("--urdf", type=Path, default=None, help="URDF file to write")
    e.add_argument("--deltas", type=Path, default=None,
                   help="CSV of the identified parameters: name,unit,nominal,estimate,delta,sigma (and held ones)")
    e.set_defaults(func=_cmd_export)

    o = sub.add_parser("online", help="incremental calibration as poses arrive (iSAM2, iterated EKF, UKF)")
    o.add_argument("dataset", type=Path)
    o.add_argument("--engine", choices=("isam2", "ekf", "ukf"), default="isam2")
    o.add_argument("--out", type=Path, default=None, help="result file (fgcal-result/1) at the end")
    o.add_argument("--checkpoint", type=Path, default=None,
                   help="state after every pose (default OUT.ENGINE.checkpoint with --out, else "
                        "fgcal-online-DATASET-DIGEST-ENGINE.checkpoint here)")
    o.add_argument("--restart", action="store_true", help="ignore an existing checkpoint and start over")
    o.add_argument("--follow", action="store_true", help="keep reading poses appended to the dataset")
    o.add_argument("--stdin", action="store_true",
                   help="read poses from standard input (DATASET gives robot, tool and noise); "
                        "records: joints,POSE,q1..q6 / probe,POSE,BALL,x,y,z / centre,... / pose,... / end,POSE")
    o.add_argument("--interval", type=positive_float, default=1.0, help="seconds between polls with --follow")
    o.add_argument("--plot", type=Path, default=None, help="convergence plot (PNG) at the end")
    o.add_argument("--drift", type=finite_float, nargs=2, metavar=("MM", "DEG"), default=None,
                   help="random-walk drift of the parameters per pose for ekf/ukf (default none)")
    o.set_defaults(func=_cmd_online)

    st = sub.add_parser("study", help="simulation studies: the paper's Figs. 8, 9, 13, its experiment, noise sweeps")
    st.add_argument("name", choices=("fig8-9", "fig13", "experiment", "sweep-cmm", "sweep-joint",
                                     "sweep-repeatability", "design"))
    st.add_argument("--out", type=Path, default=None, help="output directory (default study-NAME); resumes")
    st.add_argument("--trials", type=positive_int, default=None, help="trials (per point for fig8-9, experiment, sweeps)")
    st.add_argument("--poses", type=positive_int, default=None, help="observations per calibration (fig13, sweeps)")
    st.add_argument("--seed", type=nonnegative_int, default=0)
    st.add_argument("--workers", type=positive_int, default=None, help="local processes (default: all cores)")
    st.add_argument("--scheduler", default=None, help="Dask distributed scheduler address, e.g. tcp://host:8786")
    st.set_defaults(func=_cmd_study)

    de = sub.add_parser("design", help="which poses to measure: an optimal plan from a candidate pool")
    de.add_argument("--dataset", type=Path, default=None,
                    help="design for this dataset's robot, tool, measurement type and noise; its poses are the "
                         "candidates unless --candidates FILE")
    de.add_argument("--robot", default="puma560", help="without --dataset: the robot to plan for")
    de.add_argument("--level", choices=("probes", "centres", "poses"), default="probes",
                    help="without --dataset: what is measured at a pose (default probes on 3 balls)")
    de.add_argument("--poses", type=positive_int, default=12)
    de.add_argument("--per-placement", action="store_true",
                    help="with --dataset of contacts: --poses at each placement (fixtures linked by known "
                         "distances) instead of in all")
    de.add_argument("--candidates", default=None,
                    help="with --dataset: a joints.csv-like file of candidate poses (pose,q1..q6 deg); "
                         "without: the number of random reachable candidates (default 2000)")
    de.add_argument("--index", choices=("O1", "O2", "O3", "O4", "O5", "pred"), default=None,
                    help="criterion: observability index O1-O5, or pred (predicted accuracy; default)")
    de.add_argument("--seed", type=nonnegative_int, default=0)
    de.add_argument("--noise", choices=("estimated", "declared"), default="estimated",
                    help="with --dataset: design for the noise a calibration of it estimates (default) or its "
                         "declared noise")
    de.add_argument("--cmm-sigma", type=nonnegative_float, default=0.01)
    de.add_argument("--joint-resolution", type=nonnegative_float, default=0.01)
    de.add_argument("--repeatability", type=nonnegative_float, default=0.0)
    de.add_argument("--out", type=Path, required=True, help="plan CSV: pose,q1..q6 (deg); the candidates' pose ids")
    de.set_defaults(func=_cmd_design)

    d = sub.add_parser("demo", help="run the main job on the bundled dataset")
    d.add_argument("--out", type=Path, default=Path("fgcal-demo"), help="output directory (default fgcal-demo)")
    d.set_defaults(func=_cmd_demo)
    return p


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING,
                        format="%(levelname)s: %(message)s")
    try:
        return args.func(args)
    except FgcalError as exc:
        print(f"fgcal: error: {exc}", file=sys.stderr)
        return 2
    except NotImplementedError as exc:  # a combination not supported yet (an engine without a measurement type)
        print(f"fgcal: error: not supported yet by this command or engine: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("fgcal: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:  # output piped into head and the like
        sys.stderr.close()
        return 0
    except OSError as exc:
        print(f"fgcal: error: {os_error_message(exc)}", file=sys.stderr)
        return 2
    except MemoryError:
        print("fgcal: error: out of memory: the input is too large for this command on this machine",
              file=sys.stderr)
        return 2

