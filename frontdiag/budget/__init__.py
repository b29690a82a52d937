"""The frontend's latency budget: derived from per-unit coefficients, or measured and projected.

The library API (the CLI only renders these)::

    from frontdiag.budget import Workload, budget, compare, load_target
    report = budget(Workload(), load_target("orin-nano"))
    report.camera.total_ms, report.camera.utilisation

Calibration (:func:`frontdiag.budget.calibrate.calibrate`) and measured mode
(:func:`frontdiag.budget.measured.measured_report`) import OpenCV/pandas and live in their own
modules.
"""

from frontdiag.budget.model import BudgetReport, Comparison, SensorBudget, Workload, budget, compare
from frontdiag.budget.targets import Target, available_targets, load_target

__all__ = ["BudgetReport", "Comparison", "SensorBudget", "Target", "Workload",
           "available_targets", "budget", "compare", "load_target"]
