"""The ground floor: safe YAML reading and atomic file writing, the bundled data's folder; every layer may import them.

Nothing is imported here: import the modules themselves (no side effects, no heavy imports).
"""
