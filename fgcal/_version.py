"""The package's version, on the ground floor: any module may import it (``fgcal/__init__.py`` too)."""
__version__ = "0.1.0"
