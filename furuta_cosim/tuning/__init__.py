"""Tuning controllers by Bayesian optimization (scikit-optimize's GP + Expected Improvement)
over a spec: a search space of generalized controllers, an objective, constraints."""
