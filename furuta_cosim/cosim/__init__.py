"""Co-simulation: Python controllers sampling the plant FMU, references, noise, traces."""
