"""p/tau-adaptive computed-torque controller of the planar biped (Chevallereau & Adouane)."""
