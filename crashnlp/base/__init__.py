"""What every layer uses: the error types, units at the edges, the registry of named outputs
and metrics, the cache folder. Imports nothing of crashnlp's above it."""
