"""Confidence bands on the step, impulse and frequency responses of parametric models.

MATLAB shows them with ``showConfidence`` and returns them from ``step``,
``impulse`` and ``bode`` (``ysd``, ``sdmag``, ``sdphase``). Here
:func:`step_band`, :func:`impulse_band` and :func:`bode_band` return a
:class:`Band` (value and one standard deviation) for any model with
``parameters``, ``covariance`` and ``with_parameters`` (``PolyModel``,
``SSModel``).

Two propagations of the parameter covariance Σ:

- ``'linear'`` (default, MATLAB's): first order, Var f = Jᵀ Σ J, with the
  derivatives taken along the principal directions of Σ by central
  differences — so a rank-deficient Σ (a free state-space parameterisation)
  needs only as many evaluations as its rank.
- ``'montecarlo'``: parameters drawn from N(θ̂, Σ) with a seeded generator;
  the standard deviation of the responses over the draws.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from rwlab.errors import ModelError

__all__ = ["Band", "bode_band", "impulse_band", "step_band"]


@dataclass(frozen=True)
class Band:
    """A response with its standard deviation.

    Attributes
    ----------
    x : numpy.ndarray, shape (n,)
        Time in seconds (step, impulse) or frequency in rad/s (Bode).
    value : numpy.ndarray, shape (n, ny, nu)
        The nominal model's response.
    sd : numpy.ndarray, shape (n, ny, nu)
        One standard deviation.
    """

    x: np.ndarray
    value: np.ndarray
    sd: np.ndarray

    def lower(self, k: float = 3.0) -> np.ndarray:
        """value − k·sd."""
        return self.value - k * self.sd

    def upper(self, k: float = 3.0) -> np.ndarray:
        """value + k·sd."""
        return self.value + k * self.sd


def _as_3d(model, values: np.ndarray) -> np.ndarray:
    """A PolyModel's (n,) or (nu, n) response as (n, 1, nu); a state-space one is already 3-D."""
    if values.ndim == 3:
        return values
    return np.atleast_2d(values).reshape(-1, values.shape[-1]).T[:, None, :]


def _poly_stack(model, method: str, n: int) -> np.ndarray:
    return np.stack([getattr(model, method)(n, j) for j in range(model.nu)], axis=-1)[:, None, :]


def _step(model, n: int) -> np.ndarray:
    if hasattr(model, "ny"):
        return model.step_response(n)
    return _poly_stack(model, "step_response", n)


def _impulse(model, n: int) -> np.ndarray:
    if hasattr(model, "ny"):
        return model.impulse_response(n)
    return _poly_stack(model, "impulse_response", n)


def _freq(model, omega: np.ndarray) -> np.ndarray:
    return _as_3d(model, np.asarray(model.frequency_response(omega)))


def _propagate(model, f: Callable, method: str, n_samples: int, seed) -> np.ndarray:
    """Standard deviation of f(model) under the model's parameter covariance."""
    cov = getattr(model, "covariance", None)
    if cov is None:
        raise ModelError(
            "the model has no parameter covariance (e.g. an n4sid estimate); "
            "estimate it with a prediction-error method (ssest, arx, armax, ...)"
        )
    if method not in ("linear", "montecarlo"):
        raise ModelError(f"method must be 'linear' or 'montecarlo', got {method!r}")
    theta = model.parameters
    s, V = np.linalg.eigh((cov + cov.T) / 2)
    keep = s > 1e-12 * max(s.max(), 1e-300)
    root = V[:, keep] * np.sqrt(s[keep])  # Σ = root rootᵀ
    if method == "linear":
        h = 1e-3  # a thousandth of a standard deviation along each principal direction
        var = 0.0
        for col in root.T:
            d = f(model.with_parameters(theta + h * col)) - f(
                model.with_parameters(theta - h * col)
            )
            var = var + (d / (2 * h)) ** 2
        return np.sqrt(var) if root.shape[1] else np.zeros_like(f(model))
    rng = np.random.default_rng(seed)
    draws = []
    for z in rng.standard_normal((int(n_samples), root.shape[1])):
        value = f(model.with_parameters(theta + root @ z))
        if np.all(np.isfinite(value)):
            draws.append(value)
    if len(draws) < 2:
        raise ModelError("every Monte Carlo draw gave a non-finite response")
    return np.std(draws, axis=0, ddof=1)


def step_band(model, n: int, *, method: str = "linear", n_samples: int = 500, seed=None) -> Band:
    """Unit-step response over ``n`` samples with its standard deviation (MATLAB ``step``'s ysd).

    Parameters
    ----------
    model : PolyModel or SSModel
        A model with a parameter covariance.
    n : int
        Number of samples.
    method, n_samples, seed
        As for :func:`bode_band`.

    Returns
    -------
    Band
        The step response and its standard deviation, shape (n, ny, nu).
    """
    return _time_band(model, n, _step, method, n_samples, seed)


def impulse_band(model, n: int, *, method: str = "linear", n_samples: int = 500, seed=None) -> Band:
    """Unit-pulse response over ``n`` samples with its standard deviation.

    Parameters
    ----------
    model, n, method, n_samples, seed
        As for :func:`step_band`.

    Returns
    -------
    Band
        The pulse response and its standard deviation, shape (n, ny, nu).
    """
    return _time_band(model, n, _impulse, method, n_samples, seed)


def _time_band(model, n: int, response, method: str, n_samples: int, seed) -> Band:
    f = lambda m: response(m, n)  # noqa: E731
    return Band(np.arange(n) * model.Ts, f(model), _propagate(model, f, method, n_samples, seed))


def bode_band(
    model, omega, *, method: str = "linear", n_samples: int = 500, seed=None
) -> tuple[Band, Band]:
    """Magnitude |G| and phase (degrees) at ``omega`` (rad/s), each with its standard deviation.

    The phase of a perturbed model is measured relative to the nominal one, so
    phase wrapping never inflates its spread.

    Parameters
    ----------
    model : PolyModel or SSModel
        A model with a parameter covariance.
    omega : array_like, shape (nw,)
        Frequencies, rad/s.
    method : {'linear', 'montecarlo'}
        First-order propagation, or sampling the parameters.
    n_samples : int
        Samples for 'montecarlo'.
    seed : int or numpy.random.Generator, optional
        Random source for 'montecarlo'.

    Returns
    -------
    magnitude, phase : Band
        The magnitude |G| and the phase in degrees, each with one standard deviation.
    """
    w = np.atleast_1d(np.asarray(omega, dtype=float))
    G0 = _freq(model, w)
    mag = lambda m: np.abs(_freq(m, w))  # noqa: E731
    phase = lambda m: np.degrees(np.angle(_freq(m, w) / G0))  # noqa: E731
    nominal_phase = np.degrees(np.unwrap(np.angle(G0), axis=0))
    return (
        Band(w, np.abs(G0), _propagate(model, mag, method, n_samples, seed)),
        Band(w, nominal_phase, _propagate(model, phase, method, n_samples, seed)),
    )
