"""``fgcal simulate``: the command's body (its options are in :func:`fgcal.cli.build_parser`)."""
from __future__ import annotations

import logging
import os
import sys
from pathlib import Path

import numpy as np

from fgcal.cli.commands.checks import MAX_POSES, check_output_dir
from fgcal.errors import FgcalError

log = logging.getLogger("fgcal")


def _cmd_simulate(args) -> int:
    from dataclasses import replace

    from fgcal.io.dataset_io import save_dataset
    from fgcal.measurements.dataset import Noise
    from fgcal.robots.deviations import Deviations
    from fgcal.robots.model import Tooling
    from fgcal.robots.robot_file import load_model
    from fgcal.studies.simulate import SimulationSettings, simulate

    if args.cmm_sigma < 0 or args.joint_resolution < 0 or args.repeatability < 0:
        raise FgcalError("--cmm-sigma, --joint-resolution and --repeatability must not be negative")
    if not 0 <= args.outliers < 1:
        raise FgcalError("--outliers is a fraction of probe points, from 0 to below 1")
    if (args.poses or 0) > MAX_POSES or args.probes_per_ball > 1000:
        raise FgcalError(f"--poses at most {MAX_POSES} and --probes-per-ball at most 1000 (a dataset that large "
                         "would not fit in memory)")
    check_output_dir(args.out, [args.truth, Path(args.robot)], option="OUT", must_be_new=True, force=args.force)
    chain = None
    if args.chain:
        parts = args.chain.split(",")
        if len(parts) != 2 or not all(parts):
            raise FgcalError(f"--chain: expected BASE,TIP (URDF link names), got {args.chain!r}")
        chain = {"base": parts[0], "tip": parts[1]}
    model = load_model(args.robot, chain=chain)
    levels = args.levels
    if args.reflector is not None and args.tool_ball is not None:
        raise FgcalError("--reflector and --tool-ball: give one tool (a reflector, or a ball that touches)")
    if args.reflector is not None:
        model = replace(model, tooling=Tooling(0.0, {"R": _floats(args.reflector, 3, "--reflector")}))
        levels = levels or "centres"
    if args.tool_ball is not None:
        model = replace(model, tooling=_tool_ball(args.tool_ball))
    setup = setup_simulation(args)
    contact_levels = [lv for lv, on in (("contacts", args.sockets or args.datum), ("plane_contacts", args.plane))
                      if on]
    if contact_levels:
        levels = ",".join(([levels] if levels else []) + contact_levels)
    robot_ref = args.robot
    if Path(args.robot).suffix or "/" in args.robot:  # a file: name it relative to the dataset directory
        robot_ref = os.path.relpath(Path(args.robot).resolve(), Path(args.out).resolve())
    settings = SimulationSettings(
        n_poses=args.poses, plan=args.plan,
        noise=Noise(args.cmm_sigma, args.joint_resolution, args.repeatability),
        deviations=Deviations(args.length_sigma, args.angle_sigma, args.base_length_sigma, args.base_angle_sigma),
        n_balls=args.balls if args.balls is not None else min(3, len(model.tooling.balls) if model.tooling else 3),
        probes_per_ball=args.probes_per_ball, outlier_fraction=args.outliers,
        outlier_size=args.outlier_size, levels=tuple((levels or "probes").split(",")), setup=setup)
    truth = None
    if args.truth is not None:
        from fgcal.io.dataset_io import load_truth

        values, _ = load_truth(args.truth)
        missing = [n for n in model.slot_names if n not in values]
        if missing:
            raise FgcalError(f"{args.truth}: lacks {', '.join(missing[:5])}{' ...' if len(missing) > 5 else ''}")
        truth = model.slots_from_file_units(np.array([values[n] for n in model.slot_names]))
    ds, notes = simulate(model, np.random.default_rng(args.seed), settings, robot_ref=robot_ref, seed=args.seed,
                         truth=truth)
    ds.chain = chain
    for note in notes:
        print(f"note: {note}", file=sys.stderr)
    save_dataset(ds, args.out, overwrite=args.force)
    counts = ", ".join(f"{len(getattr(ds, lv))} {lv}" for lv in ds.levels())
    plan = f" ({args.plan} plan)" if ds.provenance.get("plan") else ""
    print(f"wrote {args.out}: {ds.n_poses} poses{plan}, {counts}; truth in truth.yaml")
    return 0


def add_setup_options(s) -> None:
    """The options of ``fgcal simulate`` for contacts and stations (DESIGN.md 8.2, 8.3)."""
    from fgcal.cli.commands.checks import nonnegative_float, nonnegative_int, positive_float, positive_int

    g = s.add_argument_group("contacts and stations (no instrument in the world frame)")
    g.add_argument("--tool-ball", default=None, metavar="X,Y,Z[,RADIUS]",
                   help="the tool ball that touches fixtures and planes: its centre in the tool frame and its "
                        "radius, mm (default radius 0); replaces the model's tooling (default: its first ball)")
    g.add_argument("--sockets", type=nonnegative_int, default=0, metavar="N",
                   help="N placements of a two-socket plate (fixtures pK/hole_0, pK/hole_1, their distance known); "
                        "writes contacts.csv")
    g.add_argument("--socket-distance", type=positive_float, default=50.0, metavar="MM",
                   help="distance between a plate's two sockets, mm (default 50)")
    g.add_argument("--distance-sigma", type=positive_float, default=0.005, metavar="MM",
                   help="declared sigma of that distance, mm (default 0.005; the simulated plate is exact)")
    g.add_argument("--configs", type=positive_int, default=10, metavar="N",
                   help="joint configurations per socket (default 10)")
    g.add_argument("--datum", type=nonnegative_int, default=0, metavar="N",
                   help="N configurations at a datum point (fixture datum)")
    g.add_argument("--datum-sigma", type=nonnegative_float, default=None, metavar="MM",
                   help="the datum's position is known with this sigma, mm (0: exactly; default unknown)")
    g.add_argument("--plane", type=nonnegative_int, default=0, metavar="N",
                   help="N contacts of the tool ball on a plane (fixture table)")
    g.add_argument("--plane-tilt", type=nonnegative_float, default=10.0, metavar="DEG",
                   help="the plane's normal is tilted from the world z by up to this, deg (default 10)")
    g.add_argument("--patch-radius", type=positive_float, default=200.0, metavar="MM",
                   help="the plane's contacts spread over a disc of this radius, mm (default 200)")
    g.add_argument("--contact-sigma", type=positive_float, default=0.02, metavar="MM",
                   help="seating error of the ball in a socket or on the plane, mm per axis (default 0.02)")
    g.add_argument("--stations", type=positive_int, default=1, metavar="N",
                   help="the centres measured from N instrument stations in turn (S1 is the world; each other "
                        "one's frame is unknown); joints.csv gets a station column")


def setup_simulation(args):
    """The :class:`~fgcal.studies.simulate_setup.SetupSimulation` of the parsed options."""
    from fgcal.studies.simulate_setup import SetupSimulation

    return SetupSimulation(placements=args.sockets, socket_distance=args.socket_distance,
                           distance_sigma=args.distance_sigma, configs=args.configs, datum=args.datum,
                           datum_sigma=args.datum_sigma, plane=args.plane, plane_tilt=args.plane_tilt,
                           patch_radius=args.patch_radius, contact_sigma=args.contact_sigma,
                           stations=args.stations)


def _tool_ball(text: str):
    from fgcal.robots.model import Tooling

    parts = text.split(",")
    values = _floats(text, len(parts) if len(parts) in (3, 4) else 3, "--tool-ball")
    radius = float(values[3]) if len(values) == 4 else 0.0
    if radius < 0:
        raise FgcalError(f"--tool-ball: the radius must not be negative, got {radius!r}")
    return Tooling(radius, {"B": values[:3]})


def _floats(text: str, n: int, option: str) -> np.ndarray:
    try:
        values = np.array([float(v) for v in text.split(",")])
    except ValueError:
        values = np.zeros(0)
    if values.shape != (n,) or not np.all(np.isfinite(values)):
        raise FgcalError(f"{option}: expected {n} comma-separated numbers, got {text!r}")
    return values
