"""``fgcal online --model``: following a drifting robot one pose ahead (:func:`fgcal.api.drift.follow`)."""
from __future__ import annotations

from fgcal.cli.commands.checks import check_output_file, dataset_inputs
from fgcal.errors import FgcalError

NOT_WITH_MODEL = ("stdin", "follow", "checkpoint", "restart", "plot")  # the engines' options a drift run has not


def cmd_online_drift(args) -> int:
    from fgcal.api.drift import follow
    from fgcal.online.drift_result import save_drift_result

    given = [name for name in NOT_WITH_MODEL if getattr(args, name, None)]
    if given:
        raise FgcalError(f"--model follows the dataset's poses in one run: --{given[0]} is for the engines without it")
    if args.engine not in ("isam2", "ekf"):  # isam2: the parser's default
        raise FgcalError(f"--model runs its own iterated EKF: --engine {args.engine} does not apply")
    if args.out:
        check_output_file(args.out, [*dataset_inputs(args.dataset)])
    result = follow(args.dataset, model=args.model, harmonics=args.harmonics, map_sigma_urad=args.map_sigma,
                    joint_errors=args.joint_errors, drift=args.drift, map_drift_urad=args.map_drift,
                    train=args.train, baseline=args.baseline)
    s = result.summary()
    lv = result.levels
    how = f"chosen on the first {result.train} poses" if result.choice else "given"
    print(f"drift per pose: {lv.length_mm:g} mm, {lv.angle_deg:g} deg, map {lv.map_urad:g} urad, compliance "
          f"{lv.compliance_urad_per_nm:g} urad/Nm; noise factor {result.extra.get('noise_factor', 1.0):g} ({how})")
    print(f"one-step-ahead position error over the {s['n']} poses after them: mean {s['mean']:.4f} mm, "
          f"RMS {s['rms']:.4f}, max {s['max']:.4f}" + (f"; {len(s['not_taken'])} not taken (implausible innovation)"
                                                      if s["not_taken"] else ""))
    base = result.extra.get("baseline")
    if base:
        b = base["summary"]
        print(f"the batch result at the same poses: mean {b['mean']:.4f} mm, RMS {b['rms']:.4f}, max {b['max']:.4f}")
    if args.out:
        save_drift_result(result, args.out)
        print(f"wrote {args.out} (fgcal-drift/1)")
    return 0
