"""Studies: simulation, experiment design and the paper's simulation studies.

Nothing is imported here: import the modules themselves (no side effects, no heavy imports).
"""
