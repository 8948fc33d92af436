"""Inertial parameter estimation: batch maximum likelihood and a sequential filter (Doerr 2021 Eqs. 31-32)."""
