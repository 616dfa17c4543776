"""Known objects, scan plans and simulated scans: the ground truth the tests and the demo
score against."""

from .hostile import SceneCapture, simulate_hostile_scan
from .objects import OBJECT_NAMES, SyntheticObject, make_object
from .plan import ring_plan
from .synthetic import Capture, carving_box, score_against_truth, simulate_scan

__all__ = ["OBJECT_NAMES", "Capture", "SceneCapture", "SyntheticObject", "carving_box",
           "make_object", "ring_plan", "score_against_truth", "simulate_hostile_scan",
           "simulate_scan"]
