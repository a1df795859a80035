"""semmap's version (one place; the package, the CLI and every map folder report it)."""

__version__ = "0.1.0"
