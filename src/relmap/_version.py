"""relmap's version, in one place (the package, the CLI and the Dask worker check read it)."""

__version__ = "0.1.0"
