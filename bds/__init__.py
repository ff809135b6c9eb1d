"""Bayesian Diversity Search (thesis §3.5): Gaussian process, acquisition, search loops."""
