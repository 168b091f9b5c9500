"""Decomposition of the normal matrix of the least-squares solver, with rank diagnostics.

The normal matrix is Jacobi-equilibrated, ``N_s = D^-1 N D^-1`` with ``D = sqrt(diag N)``, and
decomposed with a symmetric eigen-decomposition (:func:`decompose`): its condition number,
the parameters no observation constrains and the near-null directions (named by the
parameters that take part in them, :func:`summarize_names`) make the :class:`Decomposition`.
:func:`damped_step` solves the (Marquardt-damped) normal equations from it and
:func:`inverse_diagonal` gives ``diag(N^-1)``. The numerics are described in the docstring of
:mod:`calibrate.lsq`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

__all__ = ["WARN_CONDITION", "Decomposition", "covariance_sigma", "damped_step", "decompose", "inverse_diagonal",
           "summarize_names"]

#: eigenvector components at least this fraction of the largest name a near-null direction
_PARTICIPATION = 0.3
#: directions whose eigenvalue is this many times below the largest are listed as warnings
WARN_CONDITION = 1e7


# --------------------------------------------------------------------------- names
def summarize_names(names: Sequence[str], universe: Sequence[str] | None = None, *, limit: int = 12) -> str:
    """Compact, readable list of parameter names.

    Names sharing a dotted prefix are written ``prefix.*`` when every name of ``universe``
    (default: ``names``) with that prefix is in ``names``, e.g. ``B3.ccd2.*``.

    Parameters
    ----------
    names : sequence of str
        Names to list.
    universe : sequence of str, optional
        Every name that could appear (decides when ``prefix.*`` is exact); default ``names``.
    limit : int
        Most items written; the rest are counted (``and 3 more``).

    Returns
    -------
    str
        Comma-separated list.
    """
    names = list(dict.fromkeys(names))
    universe = list(universe) if universe is not None else names
    chosen = set(names)
    out, covered = [], set()
    for name in names:
        if name in covered:
            continue
        parts = name.split(".")
        label = name
        # the shortest complete prefix, keeping two components of long names (B3.ccd2.*)
        for cut in range(1 if len(parts) < 3 else 2, len(parts)):
            prefix = ".".join(parts[:cut]) + "."
            members = [n for n in universe if n.startswith(prefix)]
            if len(members) > 1 and all(n in chosen for n in members):
                label = prefix + "*"
                covered.update(members)
                break
        covered.add(name)
        out.append(label)
    if len(out) > limit:
        return ", ".join(out[:limit]) + f" and {len(out) - limit} more"
    return ", ".join(out)


# --------------------------------------------------------------------------- linear algebra
@dataclass
class Decomposition:
    """Equilibrated eigen-decomposition of a normal matrix (:func:`decompose`).

    Attributes
    ----------
    ok : bool
        The matrix is usable: finite, every parameter constrained, condition number at most
        the limit.
    message : str
        Why not (empty when ``ok``).
    d : ndarray, shape (P,)
        ``sqrt(diag N)``, the equilibration.
    eigval, eigvec : ndarray, shape (P,) and (P, P), or None
        Eigenvalues (ascending) and eigenvectors of ``D^-1 N D^-1``.
    condition : float
        Condition number of the equilibrated matrix (``inf`` when singular).
    unconstrained : tuple of str
        Parameters no observation constrains.
    near_dependent : list of tuple of str
        Parameters spanning each direction with an eigenvalue below ``lambda_max /``
        :data:`WARN_CONDITION`.
    """

    ok: bool
    message: str
    d: np.ndarray  # sqrt(diag N)
    eigval: np.ndarray
    eigvec: np.ndarray
    condition: float
    unconstrained: tuple
    near_dependent: list


def decompose(normal, names, max_condition):
    """Equilibrated eigen-decomposition with rank diagnostics.

    Parameters
    ----------
    normal : ndarray, shape (P, P)
        Symmetric normal matrix.
    names : sequence of str, shape (P,)
        Parameter names (messages).
    max_condition : float
        Largest acceptable condition number of the equilibrated matrix.

    Returns
    -------
    Decomposition
        ``ok=False`` with a message naming the parameters at fault; never raises.
    """
    diag = np.diag(normal).copy()
    if not np.all(np.isfinite(normal)):
        msg = "the normal equations hold NaN or infinite values"
        return Decomposition(False, msg, diag, None, None, np.inf, (), [])
    zero = ~(diag > 0.0)
    if np.any(zero):
        bad = tuple(n for n, z in zip(names, zero) if z)
        msg = f"no observations constrain {summarize_names(bad, names)}"
        return Decomposition(False, msg, np.sqrt(np.abs(diag)), None, None, np.inf, bad, [])
    d = np.sqrt(diag)
    ns = normal / np.outer(d, d)
    ns = 0.5 * (ns + ns.T)
    try:
        lam, vec = np.linalg.eigh(ns)
    except np.linalg.LinAlgError as exc:  # pragma: no cover - LAPACK failure
        return Decomposition(False, f"eigen-decomposition failed: {exc}", d, None, None, np.inf, (), [])
    lam_max = float(lam[-1])
    condition = lam_max / float(lam[0]) if lam[0] > 0.0 else np.inf

    def groups(threshold):
        out = []
        for i in np.nonzero(~(lam * threshold > lam_max))[0]:
            v = np.abs(vec[:, i])
            order = np.argsort(-v)
            keep = order[v[order] >= _PARTICIPATION * v[order[0]]]
            out.append(tuple(names[j] for j in keep))
        return out

    near = groups(WARN_CONDITION)
    if not condition <= max_condition:
        bad = "; ".join(summarize_names(g, names) for g in groups(max_condition))
        msg = (
            f"ill-conditioned normal equations (condition number {condition:.3g} > {max_condition:.3g}): "
            f"parameters {bad} are nearly dependent"
        )
        return Decomposition(False, msg, d, lam, vec, condition, (), near)
    return Decomposition(True, "", d, lam, vec, condition, (), near)


def damped_step(dec, rhs, damping):
    """``dx = D^-1 V (V^T D^-1 b) / (lambda + mu)``.

    Parameters
    ----------
    dec : Decomposition
        Of the normal matrix ``N`` (``ok``).
    rhs : ndarray, shape (P,)
        Right-hand side ``b``.
    damping : float
        Marquardt damping ``mu`` (0: Gauss-Newton step).

    Returns
    -------
    ndarray, shape (P,)
        The step ``dx`` (parameter units).
    """
    bs = rhs / dec.d
    coef = (dec.eigvec.T @ bs) / (dec.eigval + damping)
    return (dec.eigvec @ coef) / dec.d


def covariance_sigma(covariance) -> np.ndarray | None:
    """Standard deviations from a covariance matrix, shape (P,), or None without one.

    Square roots of the diagonal (parameter units), negative round-off clipped to 0.
    """
    if covariance is None:
        return None
    return np.sqrt(np.clip(np.diag(covariance), 0.0, None))


def inverse_diagonal(dec):
    """``diag(N^-1)`` from the decomposition.

    Parameters
    ----------
    dec : Decomposition
        Of the normal matrix ``N`` (``ok``).

    Returns
    -------
    ndarray, shape (P,)
        The diagonal of ``N^-1``.
    """
    return np.sum(dec.eigvec**2 / dec.eigval[None, :], axis=1) / dec.d**2
