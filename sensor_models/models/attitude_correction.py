"""Time-varying attitude correction of a push-broom model: drift and cubic B-spline in time.

The measured body -> ITRF rotation ``R(t)`` of a push-broom model is corrected by a small
body-frame rotation (docs/attitude.md):

.. math::

    R_{corr}(t) = R(t)\\, C(\\delta(t)), \\qquad
    C(\\delta) = R_z(\\delta_{yaw})\\, R_y(\\delta_{pitch})\\, R_x(\\delta_{roll})

(the installation convention, :class:`sensor_models.models.pushbroom_types.Installation`, and that of
the simulator's TRUE attitude errors). Each angle is a linear combination of basis functions of
the normalized time ``tau = (t - t0) / (t1 - t0)``:

* ``"drift"``: ``delta_a(t) = sum_{k=1..degree} c_{a,k} (2 tau - 1)^k`` (rate, optionally
  quadratic; the constant is the installation's, so it is left out);
* ``"spline"``: ``delta_a(t) = sum_j c_{a,j} B_j(tau)``, uniform cubic B-splines on
  ``n_segments`` equal intervals of ``[t0, t1]`` (``n_segments + 3`` coefficients per axis).
  Its constant mode duplicates the installation; the calibration regularizes it
  (:mod:`calibrate.attitude`).

Outside ``[t0, t1]`` a drift's polynomial continues. A spline either continues its end
polynomials (``outside="continue"``, the default, and the meaning of a file without the key) or holds
its end values (``outside="hold"``: ``delta(t) = delta(clip(t, t0, t1))``, zero rate outside).
The calibration fits a spline on the span of its observations and holds it beyond: a cubic
continued past the last GCP follows the noise of its last segment (on the full-size seed-003
scene 0.02 px at the last GCP line grew to 0.54 px 30 lines further), while the attitude itself
moves by at most its rate times the gap (5 urad of 0.3 Hz jitter: 1.9 urad in 0.2 s, 0.03 px).
Angles are radians, times seconds since the model's epoch.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from sensor_models.errors import InputError

__all__ = ["AXES", "KINDS", "OUTSIDE", "AttitudeCorrection", "rotation_matrices"]

#: body axes of the correction angles, in order
AXES = ("roll", "pitch", "yaw")
#: correction families
KINDS = ("drift", "spline")
#: behaviour of a spline outside its span
OUTSIDE = ("continue", "hold")


def _bspline_weights(x):
    """Uniform cubic B-spline weights (N, 4) and their derivatives in ``x`` for ``x`` in [0, 1)."""
    x2 = x * x
    x3 = x2 * x
    w = np.stack([(1 - x) ** 3, 3 * x3 - 6 * x2 + 4, -3 * x3 + 3 * x2 + 3 * x + 1, x3], axis=-1) / 6.0
    dw = np.stack([-3 * (1 - x) ** 2, 9 * x2 - 12 * x, -9 * x2 + 6 * x + 3, 3 * x2], axis=-1) / 6.0
    return w, dw


def rotation_matrices(angles_rad, *, derivatives: bool = True):
    """``C = Rz(yaw) Ry(pitch) Rx(roll)`` and its derivatives in each angle (closed form).

    Parameters
    ----------
    angles_rad : ndarray, shape (N, 3)
        Roll, pitch, yaw, radians.
    derivatives : bool
        Also return the derivatives.

    Returns
    -------
    c : ndarray, shape (N, 3, 3)
    dc : ndarray, shape (3, N, 3, 3)
        ``dC/droll``, ``dC/dpitch``, ``dC/dyaw``; only with ``derivatives=True``.
    """
    a = np.asarray(angles_rad, dtype=np.float64).reshape(-1, 3)
    ca, cb, cc = np.cos(a).T
    sa, sb, sc = np.sin(a).T
    zero = np.zeros_like(ca)

    def mat(*entries):
        out = np.empty((ca.size, 9))
        for i, e in enumerate(entries):  # column writes: a third of np.stack's time on 1e5 rows
            out[:, i] = e
        return out.reshape(-1, 3, 3)

    c = mat(cb * cc, sa * sb * cc - ca * sc, ca * sb * cc + sa * sc,
            cb * sc, sa * sb * sc + ca * cc, ca * sb * sc - sa * cc,
            -sb, sa * cb, ca * cb)  # fmt: skip
    if not derivatives:
        return c
    d_roll = mat(zero, ca * sb * cc + sa * sc, -sa * sb * cc + ca * sc,
                 zero, ca * sb * sc - sa * cc, -sa * sb * sc - ca * cc,
                 zero, ca * cb, -sa * cb)  # fmt: skip
    d_pitch = mat(-sb * cc, sa * cb * cc, ca * cb * cc,
                  -sb * sc, sa * cb * sc, ca * cb * sc,
                  -cb, -sa * sb, -ca * sb)  # fmt: skip
    d_yaw = mat(-cb * sc, -sa * sb * sc - ca * cc, -ca * sb * sc + sa * cc,
                cb * cc, sa * sb * cc - ca * sc, ca * sb * cc + sa * sc,
                zero, zero, zero)  # fmt: skip
    return c, np.stack([d_roll, d_pitch, d_yaw])


@dataclass(frozen=True)
class AttitudeCorrection:
    """A body-frame attitude correction ``delta(t)`` (module docstring).

    Parameters
    ----------
    kind : {"drift", "spline"}
        Basis family.
    t0_s, t1_s : float
        Time span of the basis, seconds since the model's epoch (``t1_s > t0_s``).
    n_terms : int
        ``"drift"``: polynomial degree (1 rate, 2 with the quadratic); ``"spline"``: number of
        equal segments of the span.
    coefficients_rad : ndarray, shape (3, K), optional
        Per axis (roll, pitch, yaw) the basis coefficients, radians (default zeros);
        ``K = n_terms`` for a drift, ``n_terms + 3`` for a spline.
    outside : {"continue", "hold"}
        A spline outside ``[t0_s, t1_s]``: its end polynomials continue, or it holds its end
        values (module docstring). A drift always continues.
    """

    kind: str
    t0_s: float
    t1_s: float
    n_terms: int
    coefficients_rad: np.ndarray = field(default=None)
    outside: str = "continue"

    def __post_init__(self):
        if self.kind not in KINDS:
            raise InputError(f"must be one of {', '.join(KINDS)}", field="attitude_correction.kind")
        if self.outside not in OUTSIDE:
            raise InputError(f"must be one of {', '.join(OUTSIDE)}", field="attitude_correction.outside")
        if not (np.isfinite(self.t0_s) and np.isfinite(self.t1_s) and self.t1_s > self.t0_s):
            raise InputError("needs finite t0_s < t1_s", field="attitude_correction.t1_s")
        lo, hi = (1, 3) if self.kind == "drift" else (1, 100_000)
        if not (lo <= int(self.n_terms) <= hi) or int(self.n_terms) != self.n_terms:
            raise InputError(f"must be an integer in [{lo}, {hi}]", field="attitude_correction.n_terms")
        object.__setattr__(self, "n_terms", int(self.n_terms))
        k = self.n_coefficients
        coef = np.zeros((3, k)) if self.coefficients_rad is None else np.asarray(self.coefficients_rad, float)
        if coef.shape != (3, k):
            raise InputError(f"must have shape (3, {k})", field="attitude_correction.coefficients_rad")
        if not np.all(np.isfinite(coef)):
            raise InputError("must be finite", field="attitude_correction.coefficients_rad")
        coef = coef.copy()
        coef.flags.writeable = False
        object.__setattr__(self, "coefficients_rad", coef)

    @property
    def n_coefficients(self) -> int:
        """Coefficients per axis ``K``."""
        return self.n_terms if self.kind == "drift" else self.n_terms + 3

    @property
    def knot_spacing_s(self) -> float:
        """Segment length of a spline, seconds (the span for a drift)."""
        return (self.t1_s - self.t0_s) / (self.n_terms if self.kind == "spline" else 1)

    def names(self) -> tuple[str, ...]:
        """Parameter names ``attitude.<axis>.k<j>``, axis-major (roll, pitch, yaw).

        Returns
        -------
        tuple of str
        """
        return tuple(f"attitude.{a}.k{j}" for a in AXES for j in range(self.n_coefficients))

    def with_coefficients(self, values) -> "AttitudeCorrection":
        """The same basis with new coefficients.

        Parameters
        ----------
        values : array_like, shape (3 * K,) or (3, K)
            Axis-major, radians.

        Returns
        -------
        AttitudeCorrection
        """
        v = np.asarray(values, dtype=np.float64).reshape(3, self.n_coefficients)
        return AttitudeCorrection(self.kind, self.t0_s, self.t1_s, self.n_terms, v, self.outside)

    def basis_sparse(self, seconds):
        """The basis functions that do not vanish at each time, and their time derivatives.

        Parameters
        ----------
        seconds : array_like, shape (N,)
            Seconds since the model's epoch.

        Returns
        -------
        index : ndarray of intp, shape (N, M)
            Coefficient indices (``M = 4`` for a spline, ``K`` for a drift).
        b, db_dt : ndarray, shape (N, M)
            Values and derivatives per second.
        """
        t = np.asarray(seconds, dtype=np.float64).reshape(-1)
        span = self.t1_s - self.t0_s
        tau = (t - self.t0_s) / span
        if self.kind == "drift":
            x = 2.0 * tau - 1.0
            k = np.arange(1, self.n_terms + 1)
            index = np.broadcast_to(np.arange(self.n_terms), (t.size, self.n_terms))
            return index, x[:, None] ** k, k * x[:, None] ** (k - 1) * (2.0 / span)
        held = self.outside == "hold"
        u = (np.clip(tau, 0.0, 1.0) if held else tau) * self.n_terms
        j = np.clip(np.floor(u).astype(np.intp), 0, self.n_terms - 1)
        w, dw = _bspline_weights(u - j)
        dw = dw * (self.n_terms / span)
        if held:
            dw[(tau < 0.0) | (tau > 1.0)] = 0.0
        return j[:, None] + np.arange(4), w, dw

    def basis(self, seconds):
        """Basis functions and their time derivatives at ``seconds`` (dense).

        Parameters
        ----------
        seconds : array_like, shape (N,)
            Seconds since the model's epoch.

        Returns
        -------
        b : ndarray, shape (N, K)
        db_dt : ndarray, shape (N, K)
            Per second.
        """
        index, w, dw = self.basis_sparse(seconds)
        n = index.shape[0]
        b = np.zeros((n, self.n_coefficients))
        db = np.zeros_like(b)
        rows = np.arange(n)[:, None]
        b[rows, index] = w
        db[rows, index] = dw
        return b, db

    def angles(self, seconds, *, derivative: bool = False):
        """Correction angles (roll, pitch, yaw) at ``seconds``.

        Parameters
        ----------
        seconds : array_like, shape (N,)
            Seconds since the model's epoch.
        derivative : bool
            Also return the rates.

        Returns
        -------
        angles_rad : ndarray, shape (N, 3)
        rates_rad_s : ndarray, shape (N, 3)
            Only with ``derivative=True``.
        """
        index, w, dw = self.basis_sparse(seconds)
        coef = self.coefficients_rad[:, index]  # (3, N, M)
        angles = np.einsum("nm,anm->na", w, coef)
        return (angles, np.einsum("nm,anm->na", dw, coef)) if derivative else angles

    def to_dict(self) -> dict:
        """JSON form (the manifest's ``attitude_correction``, docs/manifest.md).

        Returns
        -------
        dict
        """
        out = {
            "kind": self.kind,
            "t0_s": float(self.t0_s),
            "t1_s": float(self.t1_s),
            "n_terms": int(self.n_terms),
            "coefficients_urad": {a: (self.coefficients_rad[i] * 1e6).tolist() for i, a in enumerate(AXES)},
        }
        if self.outside != "continue":  # absent: the form written before the key existed
            out["outside"] = self.outside
        return out

    @classmethod
    def from_dict(cls, d, *, field_prefix: str = "attitude_correction") -> "AttitudeCorrection":
        """Parse :meth:`to_dict`'s form strictly (unknown or missing keys are errors).

        Parameters
        ----------
        d : dict
            The JSON object.
        field_prefix : str
            Field path named in errors.

        Returns
        -------
        AttitudeCorrection
        """
        keys = {"kind", "t0_s", "t1_s", "n_terms", "coefficients_urad"}
        if not isinstance(d, dict):
            raise InputError("must be an object", field=field_prefix)
        for k in set(d) - keys - {"outside"}:
            raise InputError("unknown key", field=f"{field_prefix}.{k}")
        for k in sorted(keys - set(d)):
            raise InputError("missing", field=f"{field_prefix}.{k}")
        coef = d["coefficients_urad"]
        if not isinstance(coef, dict) or set(coef) != set(AXES):
            raise InputError(f"needs exactly {', '.join(AXES)}", field=f"{field_prefix}.coefficients_urad")
        try:
            values = np.array([np.asarray(coef[a], dtype=np.float64) for a in AXES]) * 1e-6
            outside = d.get("outside", "continue")
            if outside not in OUTSIDE:
                raise InputError(f"must be one of {', '.join(OUTSIDE)}", field=f"{field_prefix}.outside")
            return cls(str(d["kind"]), float(d["t0_s"]), float(d["t1_s"]), int(d["n_terms"]), values, outside)
        except (TypeError, ValueError) as exc:
            raise InputError(f"malformed: {exc}", field=field_prefix) from None
