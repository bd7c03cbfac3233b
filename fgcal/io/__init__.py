"""Input and output: dataset files, tables, importers of other tools' formats, targets.

Nothing is imported here: import the modules themselves (no side effects, no heavy imports).
"""
