"""Online estimation: iSAM2, EKF and UKF engines updated pose by pose, and the checkpointed command-line run.

Nothing is imported here: import the modules themselves (no side effects, no heavy imports).
"""
