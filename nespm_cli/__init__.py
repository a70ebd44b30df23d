"""nespm: batch Monte Carlo experiments for nonlinear INS/DVL navigation filters."""

__version__ = "0.1.0"
