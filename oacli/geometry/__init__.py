"""Geometry of the workspace: keep-in boxes and ellipsoidal keep-out zones."""

from oacli.geometry.shapes import Box, Ellipsoid, Scene

__all__ = ["Box", "Ellipsoid", "Scene"]
