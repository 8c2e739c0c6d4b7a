"""Regression tests: consistency, accuracy and EKF-smoother agreement pinned with bounds."""
