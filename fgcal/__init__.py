"""fgcal: robot arm geometry calibration as a probabilistic factor graph.

Five lines to a simulated dataset::

    import numpy as np
    from fgcal import load_model, simulate, SimulationSettings
    model = load_model("puma560")
    dataset, notes = simulate(model, np.random.default_rng(0), SimulationSettings(n_poses=21))
"""
from fgcal._version import __version__
from fgcal.errors import DatasetError, FgcalError, ModelError
from fgcal.io.dataset_io import dataset_model, load_dataset, save_dataset
from fgcal.measurements.dataset import Dataset, Noise
from fgcal.robots.deviations import Deviations
from fgcal.robots.model import ParameterSet, RobotModel
from fgcal.robots.robot_file import load_model, save_model
from fgcal.studies.simulate import SimulationSettings, simulate

__all__ = [
           "Dataset",
           "DatasetError",
           "Deviations",
           "FgcalError",
           "ModelError",
           "Noise",
           "ParameterSet",
           "RobotModel",
           "SimulationSettings",
           "__version__",
           "dataset_model",
           "load_dataset",
           "load_model",
           "save_dataset",
           "save_model",
           "simulate",
]
