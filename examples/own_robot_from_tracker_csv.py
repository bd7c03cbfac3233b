"""Your own robot from a tracker CSV: import, check, calibrate, verify, report, export.

A laser tracker measured a reflector on a UR10's flange at 80 poses; the export is one CSV row per
pose with the six joint readings in radians and the measured point in metres, in the tracker's
frame. (This script first makes such a file from a simulated UR10, so that it runs anywhere;
with a real file start at step 1.)

Run: ``python examples/own_robot_from_tracker_csv.py [WORKDIR]`` (default: a temporary folder).
"""
from __future__ import annotations

import sys
import tempfile
import warnings
from pathlib import Path

import numpy as np

import fgcal
from fgcal.io.importer import to_datasets
from fgcal.io.table_io import ColumnSpec, read_measurements


def make_tracker_csv(path: Path, poses: int = 80, seed: int = 7) -> None:
    """A tracker export of a simulated UR10 (its true geometry off the nominal by typical amounts)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", fgcal.FgcalNote)  # poses the tracker could not see
        ds = fgcal.simulate("ur10", poses=poses, seed=seed, reflector="0,0,80", cmm_sigma=0.02,
                            joint_resolution=0.0)
    q = np.radians(ds.joints_deg)
    xyz = ds.centres.xyz[np.argsort(ds.centres.pose)] / 1000.0  # mm -> m, one reflector per pose
    lines = ["q1,q2,q3,q4,q5,q6,x,y,z"]
    lines += [",".join(f"{v:.9f}" for v in (*qi, *pi)) for qi, pi in zip(q, xyz, strict=True)]
    path.write_text("\n".join(lines) + "\n")


def main(work: Path) -> int:
    csv = work / "tracker.csv"
    make_tracker_csv(csv)

    # 1. Import: joints in radians, the point in metres; base and tool fitted to the data; a quarter held out.
    spec = ColumnSpec(joints=("q1", "q2", "q3", "q4", "q5", "q6"), joint_unit="rad", point=("x", "y", "z"),
                      length_unit="m")
    imported = to_datasets(read_measurements(csv, spec), "ur10", holdout=0.25, rng=np.random.default_rng(0),
                           position_sigma=0.02)
    train, held = imported.save(work / "my-ur10", overwrite=True)
    print(f"imported {imported.calibration.n_poses} + {imported.holdout.n_poses} poses; "
          f"nominal robot fitted to the data: RMS {imported.rms:.3g} mm")

    # 2. Check what the poses identify, 3. calibrate, 4. verify at the held-out poses.
    print("\n".join(fgcal.check(train).lines))
    result = fgcal.calibrate(train)
    result.save(work / "result.json")
    print("\n".join(fgcal.calibration_summary(result)[:4]))
    verification = fgcal.verify(result, held)
    print("\n".join(fgcal.verification_summary(verification)))

    # 5. Report with a verdict, 6. export the calibrated model for the controller.
    written = fgcal.report(result, work / "report", verification, tolerance=0.1, force=True)
    print(written.verdict.sentence())
    fgcal.export(result, urdf=work / "calibrated.urdf", deltas=work / "deltas.csv", force=True)
    print(f"wrote {written.path}, {work / 'calibrated.urdf'}, {work / 'deltas.csv'}")
    return 0 if written.passed else 1


if __name__ == "__main__":
    sys.exit(main(Path(sys.argv[1]) if len(sys.argv) > 1 else Path(tempfile.mkdtemp(prefix="fgcal-example-"))))
