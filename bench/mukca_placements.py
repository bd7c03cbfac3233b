"""The MUKCa baseline's data and scores (``bench/mukca_baseline.py``): the two-socket placements of a
Panda (joint readings seated in socket 0 and in socket 1) and, per placement, each socket's consistency
(the predicted ball centres' spread about their mean) and the error of the sockets' distance against the
plate's 50 mm, in mm. Standalone: numpy only.
"""
import os

import numpy as np

DEFAULT_DATA = "/work/shared/data/mukca-panda"
SOCKET_DISTANCE = 0.05     # m


# --------------------------------------------------------------------- data
def load_sets(data_dir=DEFAULT_DATA, names=None, robot="panda_2"):
    """{placement: (Q_socket0, Q_socket1)} in sorted placement order."""
    base = os.path.join(data_dir, robot)
    if names is None:
        names = sorted(d for d in os.listdir(base)
                       if os.path.isfile(os.path.join(base, d, "hole_0.csv")))
    out = {}
    for name in names:
        out[name] = tuple(np.loadtxt(os.path.join(base, name, f"hole_{k}.csv"),
                                     delimiter=",", ndmin=2) for k in (0, 1))
    return out


def _as_list(sets):
    if isinstance(sets, dict):
        return list(sets.items())
    return [(f"set{i}", s) for i, s in enumerate(sets)]


# --------------------------------------------------------------- evaluation
def scores(points_of, sets):
    """Per placement: per-socket consistency and the distance error, in mm; ``points_of(Q)`` the ball
    centres (N, 3) in metres at joint sets ``Q`` (N, 7).
    """
    out = {}
    for name, (Q0, Q1) in _as_list(sets):
        sockets, means, sq, counts = [], [], [], []
        for Q in (Q0, Q1):
            P = points_of(Q)
            m = P.mean(0)
            d = np.linalg.norm(P - m, axis=1)
            sockets.append({"n": int(len(P)),
                            "rms_mm": float(1e3 * np.sqrt(np.mean(d ** 2))),
                            "max_mm": float(1e3 * d.max()),
                            "mean_mm": [float(v) for v in 1e3 * m]})
            means.append(m)
            sq.append(np.sum(d ** 2))
            counts.append(len(P))
        dist = float(np.linalg.norm(means[0] - means[1]))
        out[name] = {
            "socket": sockets,
            "consistency_rms_mm": float(np.mean([s["rms_mm"] for s in sockets])),
            "pooled_rms_mm": float(1e3 * np.sqrt(sum(sq) / sum(counts))),
            "distance_mm": 1e3 * dist,
            "distance_error_mm": 1e3 * (dist - SOCKET_DISTANCE),
            "abs_distance_error_mm": 1e3 * abs(dist - SOCKET_DISTANCE),
        }
    return out


def summarise(per_placement):
    rows = list(per_placement.values())
    if not rows:
        return {}
    return {
        "n_placements": len(rows),
        "consistency_rms_mm": float(np.mean([r["consistency_rms_mm"] for r in rows])),
        "consistency_max_mm": float(np.mean([max(s["max_mm"] for s in r["socket"]) for r in rows])),
        "pooled_rms_mm": float(np.mean([r["pooled_rms_mm"] for r in rows])),
        "abs_distance_error_mm": float(np.mean([r["abs_distance_error_mm"] for r in rows])),
        "max_abs_distance_error_mm": float(np.max([r["abs_distance_error_mm"] for r in rows])),
    }
