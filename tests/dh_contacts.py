"""Two-socket contacts for a robot of fgcal's DH form (the UR10, the Puma: five links then Rz(q6)),
made by the independent forward kinematics of tests/plain_dh.py from a ``truth.yaml`` parameter
set, with tests/contact_sim.py's IK and seatings: a contacts dataset for a model with inertials
(the compliance model), whose robot fgcal loads by name."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import yaml
from contact_sim import _sample_joints, varied_solutions
from plain_dh import fk_from_truth


class DhChain:
    """:class:`contact_sim.UrdfChain`'s interface (what ``varied_solutions`` uses) over
    :func:`plain_dh.fk_from_truth`: six revolute joints (rad), mm; a central-difference Jacobian."""

    def __init__(self, truth: dict, limits):
        self.truth = truth
        self.limits = np.asarray(limits, dtype=float)
        self.n = 6
        self.is_revolute = np.ones(6, dtype=bool)

    def to_readings(self, q):
        return np.degrees(np.asarray(q, dtype=float))

    def fk(self, q) -> np.ndarray:
        q = np.asarray(q, dtype=float)
        if q.ndim == 1:
            return fk_from_truth(self.truth, np.degrees(q))
        return np.array([fk_from_truth(self.truth, np.degrees(qi)) for qi in q])

    def point(self, q, p_tip) -> np.ndarray:
        T = self.fk(q)
        return T[..., :3, :3] @ np.asarray(p_tip, float) + T[..., :3, 3]

    def point_and_jacobian(self, q, p_tip):
        q = np.asarray(q, dtype=float)
        T = self.fk(q)
        p = T[:3, :3] @ np.asarray(p_tip, float) + T[:3, 3]
        h = 1e-6
        J = np.empty((3, self.n))
        for k in range(self.n):
            d = np.zeros(self.n)
            d[k] = h
            J[:, k] = (self.point(q + d, p_tip) - self.point(q - d, p_tip)) / (2 * h)
        return p, T, J


def dh_two_socket_dataset(out: Path, robot: str, truth: dict, limits, rng, n_placements: int = 3,
                          configs_per_socket: int = 8, ball=(0.0, 0.0, 30.0), contact_sigma_mm: float = 0.02,
                          distance_mm: float = 50.0, distance_sigma_mm: float = 0.0005,
                          min_radius_mm: float = 300.0) -> dict:
    """Plates of two sockets ``distance_mm`` apart (a random horizontal direction), each socket
    seated in ``configs_per_socket`` configurations of the true robot ``truth`` (a seating: the
    true ball centre at the socket + N(0, contact_sigma_mm) per axis); writes ``out`` (robot
    ``robot`` by name) and returns the sockets' true points (mm, the true robot's world)."""
    chain = DhChain(truth, limits)
    ball = np.asarray(ball, dtype=float)
    sockets, q_all, fixture_of = {}, [], []
    for k in range(n_placements):
        for _ in range(50):
            s0 = chain.point(_sample_joints(chain, rng), ball)
            a = rng.uniform(0.0, 2.0 * np.pi)
            s1 = s0 + distance_mm * np.array([np.cos(a), np.sin(a), 0.0])
            if min(np.hypot(*s0[:2]), np.hypot(*s1[:2])) < min_radius_mm:
                continue
            plate = []
            for s in (s0, s1):
                sols, _ = varied_solutions(chain, lambda s=s: s + rng.normal(0.0, contact_sigma_mm, 3), ball, rng,
                                           configs_per_socket, max_attempts=10 * configs_per_socket,
                                           give_up_after=3 * configs_per_socket)
                if len(sols) < configs_per_socket:
                    break
                plate.append((s, sols))
            if len(plate) == 2:
                break
        else:
            raise RuntimeError(f"plate {k}: no two reachable sockets")
        for j, (s, sols) in enumerate(plate):
            name = f"p{k}/hole_{j}"
            sockets[name] = s
            q_all += sols
            fixture_of += [name] * len(sols)
    out = Path(out)
    out.mkdir(parents=True)
    names = list(sockets)
    meta = {"format": "fgcal-dataset/1", "robot": robot,
            "tool": {"radius": 0.0, "balls": {"B": [float(v) for v in ball]}},
            "noise": {"cmm_sigma": 0.01, "joint_resolution": 0.0, "contact_sigma": contact_sigma_mm},
            "fixtures": {n: {"type": "point"} for n in names},
            "constraints": {"distances": [[names[2 * k], names[2 * k + 1], distance_mm, distance_sigma_mm]
                                          for k in range(n_placements)]},
            "provenance": {"generator": "tests/dh_contacts.py"}}
    (out / "dataset.yaml").write_text(yaml.safe_dump(meta, sort_keys=False))
    q_deg = np.degrees(np.array(q_all))
    (out / "joints.csv").write_text("pose,q1,q2,q3,q4,q5,q6\n" + "".join(
        f"{p}," + ",".join(repr(float(v)) for v in q) + "\n" for p, q in enumerate(q_deg, start=1)))
    (out / "contacts.csv").write_text("pose,ball,fixture\n" + "".join(
        f"{p},B,{f}\n" for p, f in enumerate(fixture_of, start=1)))
    return sockets
