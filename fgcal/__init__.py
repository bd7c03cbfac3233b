"""fgcal: robot arm geometry calibration as a probabilistic factor graph.

Five lines to a simulated dataset::

    import numpy as np
    from fgcal import load_model, simulate, SimulationSettings
    model = load_model("puma560")
    dataset, notes = simulate(model, np.random.default_rng(0), SimulationSettings(n_poses=21))
"""
from fgcal._version import __version__
from fgcal.measurements.dataset import Dataset, Noise
from fgcal.io.dataset_io import dataset_model, load_dataset, save_dataset
from fgcal.errors import DatasetError, FgcalError, ModelError
from fgcal.robots.model import ParameterSet, RobotModel
from fgcal.robots.robot_file import load_model, save_model
from fgcal.robots.deviations import Deviations
from fgcal.studies.simulate import SimulationSettings, simulate

__all__ = ["Dataset", "Noise", "load_dataset", "save_dataset", "dataset_model", "FgcalError", "DatasetError",
           "ModelError", "ParameterSet", "RobotModel", "load_model", "save_model", "Deviations",
           "SimulationSettings", "simulate", "__version__"]
