"""bayesmap: Bayesian occupancy-grid mapping from range scans, with honest uncertainty."""

__version__ = "0.1.0"
