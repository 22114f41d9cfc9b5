"""Leg kinematics, leg force models (EF and the interface others implement), body drag, full-body dynamics."""
