"""Measurements: the in-memory dataset, one module per measurement type (the plug-in protocol), sphere and pose fits.

Nothing is imported here: import the modules themselves (no side effects, no heavy imports).
"""
