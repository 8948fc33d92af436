"""Global planning in the translational state space: LQR-RRT*, kinodynamic RRT and LQR shortcutting."""
