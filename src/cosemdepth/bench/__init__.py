"""Speed and memory measurement of the models (used by ``cosemdepth benchmark`` and ``benchmarks/``)."""
