"""The 32 closed-form basis functions of the paper's Eq. 17 (Fang et al. 2024, Mathematics 12:3175).

Every basis function is a product ``T_i(t) * U_j(u)`` of one of 4 time functions and one of 8
space functions (the 32 functions are exactly the 4 x 8 tensor product; paper index
``n = 8*i + j + 1``):

==  =================  ==  ==============================
i   T_i(t)             j   U_j(u)
==  =================  ==  ==============================
0   exp(+a t)          0   exp(+r u)
1   exp(-a t)          1   exp(-r u)
2   sin(a t)           2   sin(r u)
3   cos(a t)           3   cos(r u)
..                     4   exp(+rb u) sin(rb u)
..                     5   exp(+rb u) cos(rb u)
..                     6   exp(-rb u) sin(rb u)
..                     7   exp(-rb u) cos(rb u)
==  =================  ==  ==============================

with ``a = alpha`` and ``rb = r_bar = sqrt(2) r / 2``. (The paper text lost its minus signs in
extraction; the pairing above is the only one that gives 32 distinct functions.)

Which PDE do they satisfy? With ``alpha = r**2 sqrt(K/m)``: ``T_0, T_1`` have ``T'' = +a^2 T``
and ``T_2, T_3`` have ``T'' = -a^2 T``; ``U_0..U_3`` have ``U'''' = +r^4 U`` and ``U_4..U_7`` have
``U'''' = -4 rb^4 U = -r^4 U``. Hence ``m w_tt = s K w_uuuu`` with ``s = +1`` for
``(i < 2, j < 4)`` and ``(i >= 2, j >= 4)`` and ``s = -1`` for the other 16 (:func:`pde_sign`).
The physical Euler-Bernoulli beam ``m w_tt = -K w_uuuu`` is satisfied by only 16 of the 32
functions; the paper's Eq. 10 (``m w_tt = K w_uuuu`` as printed) by the other 16. Their linear
combination (Eq. 17) satisfies neither PDE in general: it is a physics-inspired function space,
not a solution of one PDE. This is verified numerically in ``tests/test_reconstruct.py``.

Conditioning: the implementation uses the *shifted* functions ``exp(a (t-1))``,
``exp(r (u-1))`` and ``exp(rb (u-1)) sin/cos(rb u)`` (constant multiples of the paper's, so the
span is identical) so that every function is bounded by 1 on ``[0, 1]``;
:func:`paper_scale` gives the factors to convert coefficients back to the paper's basis.
"""

from __future__ import annotations

import numpy as np

N_TIME = 4
N_SPACE = 8
N_BASIS = N_TIME * N_SPACE

_S2 = np.sqrt(2.0) / 2.0
# exponent multipliers lambda / r (space) and lambda / alpha (time); part: 0 = real, 1 = imag
_SPACE_LAMBDA = np.array([1, -1, 1j, 1j, (1 + 1j) * _S2, (1 + 1j) * _S2, (-1 + 1j) * _S2, (-1 + 1j) * _S2])
_SPACE_IMAG = np.array([0, 0, 1, 0, 1, 0, 1, 0], dtype=bool)
_TIME_LAMBDA = np.array([1, -1, 1j, 1j])
_TIME_IMAG = np.array([0, 0, 1, 0], dtype=bool)


def _eval(x: np.ndarray, scale, lam: np.ndarray, imag: np.ndarray, deriv: int) -> np.ndarray:
    """``d^k/dx^k`` of Re/Im ``exp(lam*scale*x - max(Re(lam)*scale, 0))``, shape
    ``scale.shape + x.shape + (len(lam),)`` (``scale`` a float or an array of rates)."""
    x = np.asarray(x, dtype=float)[..., None]
    scale = np.asarray(scale, dtype=float)
    lam_s = lam * scale.reshape(scale.shape + (1,) * x.ndim)
    shift = np.maximum(lam_s.real, 0.0)  # exp(+c x) -> exp(c (x - 1)): bounded by 1 on [0, 1]
    val = lam_s**deriv * np.exp(lam_s * x - shift)
    return np.where(imag, val.imag, val.real)


def time_basis(t, alpha: float, deriv: int = 0) -> np.ndarray:
    """The 4 (shifted) time functions or their ``deriv``-th derivative at normalised ``t``.

    Parameters
    ----------
    t : array_like, any shape
        Normalised time (the fitted frames span ``[0, 1]``).
    alpha : float
        Temporal rate ``alpha`` (1 / normalised time).
    deriv : int
        Derivative order (>= 0).

    Returns
    -------
    ndarray, shape ``t.shape + (4,)``
    """
    return _eval(t, float(alpha), _TIME_LAMBDA, _TIME_IMAG, deriv)


def space_basis(u, r: float, deriv: int = 0) -> np.ndarray:
    """The 8 (shifted) space functions or their ``deriv``-th derivative at parameter ``u``.

    Returns
    -------
    ndarray, shape ``u.shape + (8,)``
    """
    return _eval(u, float(r), _SPACE_LAMBDA, _SPACE_IMAG, deriv)


def _rates_times(x, rates) -> np.ndarray:
    """``rates[k] * x`` with shape ``(R,) + x.shape``."""
    x = np.asarray(x, dtype=float)
    rates = np.asarray(rates, dtype=float).reshape((-1,) + (1,) * x.ndim)
    return rates * x, rates


def space_basis_rates(u, r) -> np.ndarray:
    """:func:`space_basis` (values only) for several rates at once, in real arithmetic (4 exp and
    2 sin/cos pairs per point instead of 8 complex exponentials).

    Parameters
    ----------
    u : array_like, any shape
        Parameter values.
    r : array_like, shape (R,)
        Spatial rates.

    Returns
    -------
    ndarray, shape ``(R,) + u.shape + (8,)``; entry ``k`` equals ``space_basis(u, r[k])``.
    """
    a, r = _rates_times(u, r)
    b, rb = a * _S2, r * _S2
    sb, cb = np.sin(b), np.cos(b)
    ep, em = np.exp(b - rb), np.exp(-b)
    return np.stack([np.exp(a - r), np.exp(-a), np.sin(a), np.cos(a), ep * sb, ep * cb, em * sb, em * cb], axis=-1)


def time_basis_rates(t, alpha) -> np.ndarray:
    """:func:`time_basis` (values only) for several rates ``alpha`` (shape (A,)) at once, in real
    arithmetic: shape ``(A,) + t.shape + (4,)``."""
    a, alpha = _rates_times(t, alpha)
    return np.stack([np.exp(a - alpha), np.exp(-a), np.sin(a), np.cos(a)], axis=-1)


def time_basis_bound(alpha) -> np.ndarray:
    """Largest absolute value on ``[0, 1]`` of each (shifted) time function, shape ``(A, 4)`` for
    rates ``alpha`` (A,): 1 for ``exp(a (t - 1))``, ``exp(-a t)`` and ``cos(a t)``, and
    ``sin(min(a, pi / 2))`` for ``sin(a t)``."""
    alpha = np.atleast_1d(np.asarray(alpha, dtype=float))
    out = np.ones((len(alpha), N_TIME))
    out[:, 2] = np.sin(np.minimum(alpha, 0.5 * np.pi))
    return out


def basis(u, t, r: float, alpha: float, deriv_u: int = 0, deriv_t: int = 0) -> np.ndarray:
    """All 32 functions ``w_n(u, t)`` in the paper's order (n = 8 i + j + 1), shifted scaling.

    ``u`` and ``t`` broadcast against each other; result shape ``broadcast + (32,)``.
    """
    tb = time_basis(t, alpha, deriv_t)
    ub = space_basis(u, r, deriv_u)
    tb, ub = np.broadcast_arrays(tb[..., :, None], ub[..., None, :])
    return (tb * ub).reshape(tb.shape[:-2] + (N_BASIS,))


def pde_sign() -> np.ndarray:
    """``s_n`` (32,) such that ``m d2w_n/dt2 = s_n K d4w_n/du4`` when ``alpha = r^2 sqrt(K/m)``."""
    t_sign = np.real(_TIME_LAMBDA**2)          # +1, +1, -1, -1
    u_sign = np.real(_SPACE_LAMBDA**4)         # +1 x4, -1 x4
    return np.round(np.outer(t_sign, u_sign).ravel()).astype(int)


def paper_scale(r: float, alpha: float) -> np.ndarray:
    """Factors ``f_n`` (32,): ``c_paper_n = f_n * c_ours_n`` (may under/overflow for large r, alpha)."""
    with np.errstate(over="ignore", under="ignore"):
        ft = np.exp(-np.maximum((_TIME_LAMBDA * alpha).real, 0.0))
        fu = np.exp(-np.maximum((_SPACE_LAMBDA * r).real, 0.0))
    return np.outer(ft, fu).ravel()
