"""Hydrodynamics workbench for a swimming legged robot (after "Learn to Swim", ICRA 2025)."""

__version__ = "0.1.0"
