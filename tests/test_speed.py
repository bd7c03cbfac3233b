"""What the speed work must not change, and what it must not load (issue 16). No timed tests."""
import json
import subprocess
import sys

import numpy as np
import pytest

from fgcal.estimation.calibrate import CalibrationOptions, build_graph, levenberg_marquardt
from fgcal.studies.simulate import SimulationSettings, simulate

HEAVY = ("gtsam", "scipy.optimize", "scipy.stats", "matplotlib", "filterpy")


def _loaded(code: str) -> list[str]:
    out = subprocess.run([sys.executable, "-c", code + "\nimport json, sys\nprint(json.dumps(sorted(sys.modules)))"],
                         capture_output=True, text=True, check=True).stdout.splitlines()[-1]
    return [m for m in json.loads(out) if m in HEAVY]


@pytest.mark.parametrize("code", ["import fgcal", "import fgcal.estimation.calibrate",
                                  "import fgcal.cli\ntry:\n    fgcal.cli.main(['--version'])\nexcept SystemExit:\n    pass"])
def test_imports_load_nothing_unused(code):
    assert _loaded(code) == []


def test_calibrate_path_loads_nothing_unused(tmp_path, puma):
    """A whole calibration of probe data: no GTSAM (the covariance is the solve's), no scipy.optimize/stats."""
    ds, _ = simulate(puma, np.random.default_rng(5), SimulationSettings(n_poses=8))
    from fgcal.io.dataset_io import save_dataset

    save_dataset(ds, tmp_path / "d")
    code = ("from fgcal import load_dataset, dataset_model\nfrom fgcal.estimation.calibrate import calibrate\n"
            f"ds = load_dataset({str(tmp_path / 'd')!r})\nr = calibrate(ds, dataset_model(ds))\nassert r.converged")
    assert _loaded(code) == []


def test_levenberg_marquardt_stops_at_the_minimum_without_moving(puma):
    """Restarted at its own solution, LM stops at once: no step on rounding-level cost changes."""
    ds, _ = simulate(puma, np.random.default_rng(6), SimulationSettings(n_poses=30))
    graph, state, _ = build_graph(ds, puma, puma.identifiable_names(), CalibrationOptions())
    solved, iterations, converged = levenberg_marquardt(graph, state)
    assert converged and iterations < 20
    again, it2, conv2 = levenberg_marquardt(graph, solved)
    assert conv2 and it2 == 1
    cov = graph.covariance(solved)
    # the restart moves the parameters by far less than their uncertainty
    assert np.max(np.abs(again.theta - solved.theta) / np.sqrt(np.diag(cov))) < 1e-6
    assert graph.cost(again) <= graph.cost(solved)


def test_normal_equations_match_the_dense_jacobian(puma):
    """The per-pose block normal equations and Schur complement equal those of the full Jacobian."""
    ds, _ = simulate(puma, np.random.default_rng(7), SimulationSettings(n_poses=5))
    graph, state, _ = build_graph(ds, puma, puma.identifiable_names(), CalibrationOptions(prior="weak",
                                                                                         kinematic_sigma=0.01))
    lin = graph.linearise(state)  # (a looser kinematic sigma keeps the dense elimination accurate)
    n, m, P, nz = graph.n_poses, graph.m, len(state.theta), graph.nz
    J = np.zeros((n * m + len(lin.prior_r), P + n * nz))
    for i in range(n):
        J[i * m:i * m + graph.m_theta, :P] = lin.J_theta[i]
        J[i * m:(i + 1) * m, P + i * nz:P + (i + 1) * nz] = lin.J_local[i]
    J[n * m:, :P] = lin.prior_J
    used = np.concatenate([np.ones(P, bool), graph.local_used.ravel()])
    J = J[:, used]
    H = J.T @ J
    S_dense = H[:P, :P] - H[:P, P:] @ np.linalg.solve(H[P:, P:], H[P:, :P])
    S = graph.parameter_information(state, lin)
    np.testing.assert_allclose(S, S_dense, rtol=1e-9, atol=1e-9 * np.abs(S_dense).max())
    np.testing.assert_allclose(graph.covariance(state, lin), np.linalg.inv(S_dense), rtol=1e-6,
                               atol=1e-9 * np.abs(np.linalg.inv(S_dense)).max())


def test_batched_sphere_fits_of_measure_match_one_by_one(puma):
    """measure_probes fits all balls at once: the same centres, covariances and verdicts as ball by ball."""
    from fgcal.measurements.measure import measure_probes
    from fgcal.measurements.spherefit import fit_sphere

    ds, _ = simulate(puma, np.random.default_rng(8), SimulationSettings(n_poses=15, outlier_fraction=0.05))
    m = measure_probes(ds)
    pr = ds.probes
    for p, b, c, cov in zip(m.centres.pose, m.centres.ball, m.centres.xyz, m.centre_covariance):
        fit = fit_sphere(pr.xyz[(pr.pose == p) & (pr.ball == b)], radius=ds.tooling.radius, sigma=ds.noise.cmm_sigma)
        assert fit.ok
        np.testing.assert_allclose(c, fit.centre, atol=1e-9)
        np.testing.assert_allclose(cov, fit.covariance, rtol=1e-6, atol=1e-15)
    n_keys = len(set(zip(pr.pose.tolist(), pr.ball.tolist())))
    bad = [q for q in m.quality if q.ball != "*" and q.status != "ok"]
    assert len(m.centres.pose) + len(bad) == n_keys and bad  # the outliers are diagnosed, none lost
