"""Reports of runs: figures (matplotlib) and, later, regression and tuning reports."""
