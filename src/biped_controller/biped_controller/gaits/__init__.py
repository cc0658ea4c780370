"""Offline gait generation: the optimal step and the family q_d(p, tau) fitted over p."""
