"""Studies: simulation, experiment design, the paper's simulation studies and the honesty scenarios.

Nothing is imported here: import the modules themselves (no side effects, no heavy imports).
"""
