"""Rigid-body dynamics, computed-torque control and co-simulation of the 3-RRR (paper eqs. 5-7)."""
