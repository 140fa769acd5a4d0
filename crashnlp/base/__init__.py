"""What every layer uses: the error types, units at the edges, the registry of named outputs
and metrics, the cache folder, crashnlp's version. Imports nothing of crashnlp's above it."""

VERSION = "0.1.0"  # crashnlp.__version__, pyproject.toml's version: here, where every layer may read it
