"""Online calibration from a stream: poses arrive one by one (a socket, a serial port, a pipe).

The records are the lines ``fgcal online DATASET --stdin`` reads (``joints,POSE,q1..qn`` then
``probe,POSE,BALL,x,y,z`` ...; see :data:`fgcal.online.stream.STREAM_FORMAT`). Here they come from
a generator over a simulated session; the estimate and its sigma are there after every pose, and
the final smoothing ends at the batch calibration of the same poses.

Run: ``python examples/online_from_stream.py [WORKDIR]``.
"""
from __future__ import annotations

import sys
import tempfile
from collections.abc import Iterator
from pathlib import Path

import numpy as np

import fgcal
from fgcal.io.dataset_io import load_dataset_meta
from fgcal.online.run import OnlineRun
from fgcal.online.stream import read_stream


def session(ds) -> Iterator[str]:
    """The lines an instrument and the robot controller would send, pose after pose."""
    for pose, q in zip(ds.pose_ids, ds.joints_deg, strict=True):
        yield "joints," + ",".join([str(int(pose)), *(f"{v:.6f}" for v in q)])
        mine = ds.probes.pose == pose
        for ball, xyz in zip(ds.probes.ball[mine], ds.probes.xyz[mine], strict=True):
            yield "probe," + ",".join([str(int(pose)), str(ball), *(f"{v:.6f}" for v in xyz)])
        yield f"end,{int(pose)}"


def main(work: Path) -> int:
    measured = fgcal.simulate("puma560", poses=25, seed=11, out=work / "session", force=True)
    meta = load_dataset_meta(work / "session")  # robot, tool and noise: the poses come on the stream
    model = fgcal.dataset_model(meta)
    run = OnlineRun(meta, model, "ekf", checkpoint=work / "session.ekf.checkpoint", restart=True)
    for record in read_stream(session(measured), meta.tooling.balls, model=model, setup=meta.setup):
        entry = run.feed(record, streamed=True)
        est, sig = run.estimate_file_units()
        worst = int(np.argmax(sig))
        print(f"pose {entry['pose']:3d} {'accepted' if entry['accepted'] else 'refused: ' + entry['reason']}; "
              f"least known now: {run.engine.params.names[worst]} +- {sig[worst]:.3g}")
    online = run.result()
    batch = fgcal.calibrate(work / "session")
    common = [n for n in batch.names if n in online.names]
    gap = max(abs(online.estimate[online.names.index(n)] - batch.estimate[batch.names.index(n)])
              / batch.sigma[batch.names.index(n)] for n in common)
    print(f"online result from {online.n_poses} poses; largest |online - batch| = {gap:.3g} batch sigma")
    return 0 if gap < 0.1 else 1


if __name__ == "__main__":
    sys.exit(main(Path(sys.argv[1]) if len(sys.argv) > 1 else Path(tempfile.mkdtemp(prefix="fgcal-example-"))))
