"""What a calibration result predicts of a tool point and how well (tests/test_stations.py,
test_contacts_simulated.py, test_simulate_contacts.py, online_util.py): the point at new joint
sets, its Jacobian in the result's geometric parameters and their covariance, and the same with
what a rigid motion of the world frame absorbs taken out."""
import numpy as np

from fgcal.robots.kinematics import jacobians


def predicted_points(slots, result, model, q, ball):
    """The ball at ``ball`` (3,) mm in the tool frame, at joints ``q`` (N, n) rad on the chain of
    ``slots`` (internal units): ``(points (N, 3) mm, J (N, 3, k), cov (k, k))``, with ``J`` and
    ``cov`` over the k slots among ``result``'s parameters, in internal units (mm, rad)."""
    jac = jacobians(slots, q, offsets=np.broadcast_to(ball, (len(q), 1, 3)), chain=model.chain)
    names = [n for n in result.names if n in set(model.slot_names)]
    idx = [model.slot(n) for n in names]
    cols = [result.names.index(n) for n in names]
    scale = np.where(model.slot_is_angle[idx], np.radians(1.0), 1.0)  # the covariance is in mm, deg
    cov = result.covariance[np.ix_(cols, cols)] * np.outer(scale, scale)
    return jac.points[:, 0], jac.point_slots[:, 0][:, :, idx], cov


def without_rigid_motion(points, J):
    """``J`` (3N, k) less what a rigid motion of ``points`` (N, 3) mm absorbs (the free world frame
    an aligned comparison takes out)."""
    c = points - points.mean(0)
    rigid = np.concatenate([np.broadcast_to(np.eye(3), (len(points), 3, 3)),
                            -np.array([[[0, -z, y], [z, 0, -x], [-y, x, 0]] for x, y, z in c])],
                           axis=2).reshape(-1, 6)
    return J - rigid @ np.linalg.lstsq(rigid, J, rcond=None)[0]
