"""``fgcal simulate``: the command's body (its options are in :func:`fgcal.cli.parser.build_parser`)."""
from __future__ import annotations

import logging
import sys
from pathlib import Path

from fgcal.cli.commands.checks import check_output_dir
from fgcal.cli.commands.common import call

log = logging.getLogger("fgcal")


def _cmd_simulate(args) -> int:
    """:func:`fgcal.api.simulation.simulate` with the parsed options; the output checked first."""
    from fgcal.api.simulation import simulate

    check_output_dir(args.out, [args.truth, Path(args.robot)], option="OUT", must_be_new=True, force=args.force)
    ds = call(simulate, args.robot, poses=args.poses, seed=args.seed, plan=args.plan, cmm_sigma=args.cmm_sigma,
              joint_resolution=args.joint_resolution, repeatability=args.repeatability, outliers=args.outliers,
              outlier_size=args.outlier_size, balls=args.balls, probes_per_ball=args.probes_per_ball,
              levels=args.levels, length_sigma=args.length_sigma, angle_sigma=args.angle_sigma,
              base_length_sigma=args.base_length_sigma, base_angle_sigma=args.base_angle_sigma, chain=args.chain,
              reflector=args.reflector, truth=args.truth, out=args.out, force=args.force,
              tool_ball=args.tool_ball, setup=setup_simulation(args), notes_to=sys.stderr)
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
