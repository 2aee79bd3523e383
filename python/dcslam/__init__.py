"""dcslam: Divide and Conquer EKF SLAM with data association in linear time.

Implements Paz, Guivant, Tardós, Neira, "Data Association in O(n) for Divide and Conquer
SLAM", RSS 2007. The public surface is described in ``docs/api.md``, the algorithms and
decisions in ``docs/design.md``.
"""

from ._version import __version__
from . import geometry
from ._core import InvalidArgument, ParseError
from .config import SlamConfig
from . import datasets
from .consistency import chi2_threshold, consistency_index, nees
from .simulation import REVISIT_SCENARIOS, Simulation, SimulationConfig, revisit_scenario, simulate
from .slam import BatchResult, DCSlam, DCSlamStats, EkfSlam, Estimate, SlamStats
from . import evaluation, io, metrics, pipeline
from .metrics import gps_alignment
from .pipeline import PipelineResult, SlamPipeline

__all__ = [
    "__version__",
    "datasets",
    "geometry",
    "InvalidArgument",
    "ParseError",
    "SlamConfig",
    "BatchResult",
    "DCSlam",
    "DCSlamStats",
    "EkfSlam",
    "Estimate",
    "SlamStats",
    "Simulation",
    "SimulationConfig",
    "simulate",
    "REVISIT_SCENARIOS",
    "revisit_scenario",
    "evaluation",
    "nees",
    "chi2_threshold",
    "consistency_index",
    "io",
    "metrics",
    "pipeline",
    "PipelineResult",
    "SlamPipeline",
    "gps_alignment",
]
