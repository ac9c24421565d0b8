"""Tuning controllers by constrained Bayesian optimization (Gaussian processes of the objective
and of the feasibility margin, Expected Improvement times the probability of feasibility, in a
trust region; for a trade-off of two criteria, expected hypervolume improvement) over a spec:
a search space of generalized controllers, an objective, constraints."""
