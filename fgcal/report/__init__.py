"""Reports: accuracy statistics, the uncertainty report, figures and the HTML/Markdown document.

Nothing is imported here: import the modules themselves (no side effects, no heavy imports).
"""
