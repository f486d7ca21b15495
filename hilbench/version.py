"""The package's version, in a module of its own so any layer can name it without importing the
public API (hilbench/__init__.py re-exports it; pyproject.toml states the same number)."""

__version__ = "0.2.0"

__all__ = ["__version__"]
