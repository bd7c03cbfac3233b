"""Robots: serial-chain models (built-in, model files, DH/MDH tables, URDF), kinematics, inverse kinematics and compensation;
what follows from a model alone: identifiability, gravity torques, the typical deviations from nominal.

Nothing is imported here: import the modules themselves (no side effects, no heavy imports).
"""
