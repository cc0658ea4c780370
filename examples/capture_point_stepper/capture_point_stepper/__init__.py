"""A capture-point step adjuster on the biped's gait family, as a controller plug-in (``controller``)."""
from capture_point_stepper.controller import CapturePointStepper, StepperSettings

__all__ = ["CapturePointStepper", "StepperSettings"]
