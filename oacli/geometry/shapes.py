"""Keep-in boxes and ellipsoidal keep-out zones ([Doerr2021] Eqs. 12-14)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True)
class Box:
    """Axis-aligned box ``lower <= p <= upper`` [m] (a keep-in zone)."""

    lower: np.ndarray
    upper: np.ndarray

    def __post_init__(self) -> None:
        lo = np.array(self.lower, dtype=float).reshape(3)
        hi = np.array(self.upper, dtype=float).reshape(3)
        if np.any(hi <= lo):
            raise ValueError(f"box upper {hi} must exceed lower {lo} on every axis")
        lo.setflags(write=False)
        hi.setflags(write=False)
        object.__setattr__(self, "lower", lo)
        object.__setattr__(self, "upper", hi)

    @property
    def center(self) -> np.ndarray:
        """Centre of the box [m]."""
        return 0.5 * (self.lower + self.upper)

    @property
    def size(self) -> np.ndarray:
        """Edge lengths [m]."""
        return self.upper - self.lower

    def contains(self, points: np.ndarray, margin_m: float = 0.0) -> np.ndarray:
        """True for each point (shape (..., 3)) inside the box shrunk by ``margin_m`` on every face.

        Parameters
        ----------
        points : ndarray, shape (..., 3)
            Positions [m].
        margin_m : float, optional
            Inward margin [m] on every face.

        Returns
        -------
        ndarray of bool, shape (...)
        """
        p = np.asarray(points, dtype=float)
        return np.all((p >= self.lower + margin_m) & (p <= self.upper - margin_m), axis=-1)


@dataclass(frozen=True)
class Ellipsoid:
    """Ellipsoidal keep-out zone; free space is ``(p - c)ᵀ P (p - c) >= 1`` ([Doerr2021] Eq. 12).

    Attributes
    ----------
    center : ndarray, shape (3,)
        Centroid c [m].
    shape : ndarray, shape (3, 3)
        Symmetric positive definite shape matrix P [1/m²]; its eigenvalues are 1/a_i² for semi-axes a_i.
    """

    center: np.ndarray
    shape: np.ndarray

    def __post_init__(self) -> None:
        c = np.array(self.center, dtype=float).reshape(3)
        p = np.array(self.shape, dtype=float).reshape(3, 3)
        if not np.allclose(p, p.T, rtol=1e-10, atol=1e-12):
            raise ValueError("ellipsoid shape matrix must be symmetric")
        if np.linalg.eigvalsh(p).min() <= 0:
            raise ValueError("ellipsoid shape matrix must be positive definite")
        c.setflags(write=False)
        p.setflags(write=False)
        object.__setattr__(self, "center", c)
        object.__setattr__(self, "shape", p)

    @classmethod
    def from_semi_axes(
        cls, center: np.ndarray, semi_axes_m: np.ndarray, rotation: np.ndarray | None = None
    ) -> Ellipsoid:
        """Build from semi-axes a [m] along the columns of ``rotation`` (identity by default).

        Parameters
        ----------
        center : ndarray, shape (3,)
            Centre [m].
        semi_axes_m : ndarray, shape (3,)
            Semi-axes [m], > 0.
        rotation : ndarray, shape (3, 3), optional
            Principal axes (columns) in the world frame.

        Returns
        -------
        Ellipsoid
        """
        a = np.asarray(semi_axes_m, dtype=float).reshape(3)
        r = np.eye(3) if rotation is None else np.asarray(rotation, dtype=float).reshape(3, 3)
        return cls(center, r @ np.diag(1.0 / a**2) @ r.T)

    def principal_axes(self) -> tuple[np.ndarray, np.ndarray]:
        """Semi-axes and principal directions, with ``shape = R diag(1/a²) Rᵀ`` and det R = +1.

        Returns
        -------
        semi_axes_m : ndarray, shape (3,)
        rotation : ndarray, shape (3, 3)
            ``R``, the principal directions as columns.
        """
        eigval, eigvec = np.linalg.eigh(self.shape)
        if np.linalg.det(eigvec) < 0:
            eigvec[:, 2] *= -1.0
        return 1.0 / np.sqrt(eigval), eigvec

    def inflated(self, factor: float) -> Ellipsoid:
        """The ellipsoid with every semi-axis multiplied by ``factor`` (a safety factor, [Doerr2021] Eq. 12).

        Parameters
        ----------
        factor : float
            Scale factor of the semi-axes, > 0.

        Returns
        -------
        Ellipsoid
        """
        return Ellipsoid(self.center, self.shape / factor**2)

    def contains(self, points: np.ndarray) -> np.ndarray:
        """True for each point (shape (..., 3)) strictly inside the keep-out zone.

        Parameters
        ----------
        points : ndarray, shape (..., 3)
            Positions [m].

        Returns
        -------
        ndarray of bool, shape (...)
        """
        d = np.asarray(points, dtype=float) - self.center
        return np.einsum("...i,ij,...j->...", d, self.shape, d) < 1.0


@dataclass(frozen=True)
class Scene:
    """The workspace: the union of keep-in boxes minus the keep-out ellipsoids."""

    keep_in: tuple[Box, ...] = field(default_factory=tuple)
    keep_out: tuple[Ellipsoid, ...] = field(default_factory=tuple)
    frame: str = "world"

    def in_keep_in(self, points: np.ndarray, margin_m: float = 0.0) -> np.ndarray:
        """True where a point lies in at least one keep-in box (always True when there is none).

        Parameters
        ----------
        points : ndarray, shape (..., 3)
            Positions [m].
        margin_m : float, optional
            Inward margin [m] of every box.

        Returns
        -------
        ndarray of bool, shape (...)
        """
        p = np.asarray(points, dtype=float)
        if not self.keep_in:
            return np.ones(p.shape[:-1], dtype=bool)
        return np.any([b.contains(p, margin_m) for b in self.keep_in], axis=0)

    def in_keep_out(self, points: np.ndarray) -> np.ndarray:
        """True where a point lies inside at least one keep-out ellipsoid.

        Parameters
        ----------
        points : ndarray, shape (..., 3)
            Positions [m].

        Returns
        -------
        ndarray of bool, shape (...)
        """
        p = np.asarray(points, dtype=float)
        if not self.keep_out:
            return np.zeros(p.shape[:-1], dtype=bool)
        return np.any([e.contains(p) for e in self.keep_out], axis=0)
