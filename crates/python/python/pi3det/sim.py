"""The multi-platform LiDAR simulator: ``simulate(platform="drone", sequences=2, frames=50,
seed=0)`` yields :class:`pi3det.Frame` objects, the frames ``pi3det simulate`` writes."""
from ._native import Simulation, simulate

__all__ = ["Simulation", "simulate"]
