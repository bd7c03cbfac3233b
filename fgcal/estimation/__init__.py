"""Estimation: the factor graph, the batch solve, noise and outlier handling, held parameters,
parameter blocks (joint errors), the result and its verification.

Nothing is imported here: import the modules themselves (no side effects, no heavy imports).
"""
