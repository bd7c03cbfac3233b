"""Estimation: the factor graph, the batch solve, noise and outlier handling, held parameters, parameter blocks (joint errors, gravity) and the result.

Nothing is imported here: import the modules themselves (no side effects, no heavy imports).
"""
