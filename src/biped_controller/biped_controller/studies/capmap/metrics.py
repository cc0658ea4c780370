"""Conversions of a boundary force F [N] of a push of duration d [s]: impulse, the change of the centre
of mass's velocity the push alone causes, fraction of body weight."""
from __future__ import annotations


def impulse(force: float, duration: float) -> float:
    """Impulse of a constant force [N] over ``duration`` [s]: F d [N s]."""
    return force * duration


def com_velocity_change(force: float, duration: float, mass: float) -> float:
    """Change of the centre of mass's horizontal velocity [m/s] that the push alone causes on a robot of
    total mass ``mass`` [kg]: F d / M (momentum theorem, the push as the only external impulse)."""
    return force * duration / mass


def body_weight_fraction(force: float, mass: float, gravity: float) -> float:
    """Force as a fraction of body weight: F / (M g) [-]."""
    return force / (mass * gravity)
