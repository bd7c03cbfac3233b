"""``fgcal online``: the command's body (its options are in :func:`fgcal.cli.parser.build_parser`)."""
from __future__ import annotations

import logging
import sys

import numpy as np

from fgcal.cli.commands.checks import check_output_file, dataset_inputs
from fgcal.errors import FgcalError
from fgcal.io.skipped import bounded

log = logging.getLogger("fgcal")


def _cmd_online(args) -> int:
    from fgcal.estimation.result import save_result
    from fgcal.io.dataset_io import dataset_model, load_dataset
    from fgcal.online.display import Display, follow
    from fgcal.online.run import OnlineRun

    if args.stdin and args.follow:
        raise FgcalError("--stdin and --follow: choose one source of new poses")
    if args.model is not None:
        from fgcal.cli.commands.online_drift import cmd_online_drift

        return cmd_online_drift(args)
    if args.checkpoint:  # read and appended to: it must not be one of the dataset's files
        check_output_file(args.checkpoint, [args.out, *dataset_inputs(args.dataset)], option="--checkpoint")
    if args.out:
        check_output_file(args.out, [args.checkpoint, *dataset_inputs(args.dataset)])
    if args.plot:
        check_output_file(args.plot, [args.out, args.checkpoint, *dataset_inputs(args.dataset)], option="--plot")
    if args.stdin:
        from fgcal.io.dataset_io import load_dataset_meta

        ds = load_dataset_meta(args.dataset)  # robot, tool and noise; poses come on standard input
    else:
        ds = load_dataset(args.dataset)
        from fgcal.online.records import read_levels

        unread = [lv for lv in ds.levels() if lv not in read_levels()]
        if unread:  # nothing dropped in silence
            raise FgcalError(f"{args.dataset}: the online engines do not take {', '.join(unread)} yet "
                             f"(they take {', '.join(read_levels())}); calibrate it with fgcal calibrate")
    model = dataset_model(ds)
    from fgcal.online.checkpoint import default_checkpoint

    checkpoint = args.checkpoint or default_checkpoint(args.dataset, args.engine, args.out)
    if args.drift and args.engine == "isam2":
        raise FgcalError("--drift is for the filters (ekf, ukf): iSAM2 keeps the parameters constant")
    engine_kw = {}
    if args.drift:
        length, angle = args.drift
        if length < 0 or angle < 0:
            raise FgcalError("--drift takes two non-negative numbers: mm and deg per pose")
        params = model.parameters()
        engine_kw["drift"] = np.where(params.is_angle, np.radians(angle), length)
    run = OnlineRun(ds, model, args.engine, checkpoint, engine_kw=engine_kw, restart=args.restart)
    restored = run.resume()
    if restored:
        print(f"resumed from {checkpoint}: {restored} pose(s) already processed")
    display = Display(run)
    try:
        if args.stdin:
            from fgcal.online.stream import read_stream

            for rec in read_stream(sys.stdin.buffer, ds.tooling.balls, model=model, setup=ds.setup):
                display.show(run.feed(rec, streamed=True))
        elif args.follow:
            print(f"following {args.dataset} (Ctrl-C to stop); checkpoint {checkpoint}")
            for rec in run.pending():
                display.show(run.feed(rec))
            follow(run, display, interval=args.interval)
        else:
            pending = run.pending()
            for rec in pending:
                display.show(run.feed(rec), total=ds.n_poses)
    except KeyboardInterrupt:
        print(f"\ninterrupted: {len(run.processed)} pose(s) processed, state in {checkpoint}; run again to resume")
        if not args.follow:
            return 130
    rejected = [p for p in run.processed if not p["accepted"]]
    for p in rejected:
        print(f"rejected pose {p['pose']}: {p['reason']}")
    result = run.result()
    if result.n_poses == 0:
        first = f"; pose {rejected[0]['pose']}: {bounded(rejected[0]['reason'])}" if rejected else ""
        raise FgcalError(f"{args.dataset}: no pose taken ({len(rejected)} rejected{first}); "
                         f"{'nothing written' if args.out else 'no result'} (state in {checkpoint})")
    if args.out:
        save_result(result, args.out)
        print(f"wrote {args.out} ({result.n_poses} poses, engine {args.engine})")
    if args.plot and run.history:
        import io

        from fgcal.report.plots import plot_convergence
        from fgcal.util.yamlio import atomic_write_bytes

        params = run.engine.params  # the history's columns (a parameter the final smoothing held: sigma 0)
        names = list(params.names)
        rel = np.sqrt(np.diag(params.covariance_to_file_units(run.engine.estimate()[1]))) / \
            params.to_file_units(run.engine.prior_sigma)
        show = list(np.argsort(-rel)[:6])
        n = [h["n"] for h in run.history]
        est = np.array([h["estimate"] for h in run.history])[:, show]
        sig = np.array([h["sigma"] for h in run.history])[:, show]
        ax = plot_convergence(n, est, sig, [names[i] for i in show])
        buf = io.BytesIO()
        ax.figure.savefig(buf, format="png", dpi=110)
        atomic_write_bytes(args.plot, buf.getvalue())
        print(f"wrote {args.plot}")
    return 0
