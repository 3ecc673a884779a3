"""Cheap simulations for the fitting tests, exact for a held (zero-order-hold) input
(the matrix exponential: scipy.signal.cont2discrete), and the measured data
they generate with seeded white noise."""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # 3x3 matrices: one thread is fastest

from collections.abc import Mapping  # noqa: E402

import numpy as np  # noqa: E402
import scipy.signal  # noqa: E402

from agv_cosim.fitting import MeasuredData, Parameter, measured_data  # noqa: E402

#: Sampling: 0 to 4 s every 10 ms.
TIME = np.linspace(0.0, 4.0, 401)


def command(t: np.ndarray) -> np.ndarray:
    """A held multi-step input: +1 from 0.2 s, -0.5 from 1.5 s, +0.8 from 2.6 s."""
    return np.where(t >= 0.2, 1.0, 0.0) - np.where(t >= 1.5, 1.5, 0.0) + \
        np.where(t >= 2.6, 1.3, 0.0)


def second_order(x: np.ndarray, t: np.ndarray = TIME) -> dict[str, tuple[np.ndarray,
                                                                          np.ndarray]]:
    """``K wn^2 / (s^2 + 2 zeta wn s + wn^2)`` driven by :func:`command`; x = (K, wn,
    zeta); signal "y"."""
    k, wn, zeta = (float(v) for v in x)
    a, b, c, d = scipy.signal.tf2ss([k * wn * wn], [1.0, 2.0 * zeta * wn, wn * wn])
    y = held_response((a, b, c, d), command(t), t)
    return {"y": (t.copy(), y[:, 0])}


def held_response(system: tuple[np.ndarray, ...], u: np.ndarray,
                  t: np.ndarray) -> np.ndarray:
    """The outputs (columns) of the state-space ``system`` from rest for the input ``u``
    held between the uniformly spaced ``t``: exact (zero-order-hold discretisation by
    the matrix exponential, scipy.signal.cont2discrete), run by lfilter."""
    a, b, c, d = system
    h = float(t[1] - t[0])
    ad, bd, cd, dd, _ = scipy.signal.cont2discrete((a, b, c, d), h, method="zoh")
    columns = []
    for row in range(np.atleast_2d(cd).shape[0]):
        num, den = scipy.signal.ss2tf(ad, bd, cd[row:row + 1], dd[row:row + 1])
        columns.append(scipy.signal.lfilter(num[0], den, u))
    return np.column_stack(columns)


#: (K, wn [rad/s], zeta) of the tests' second-order system.
SECOND_TRUE = np.array([0.6, 12.0, 0.35])
SECOND_PARAMETERS = (Parameter("K", 1.0, 0.1, 5.0), Parameter("wn", 20.0, 1.0, 100.0),
                     Parameter("zeta", 0.7, 0.05, 3.0))


def mass_spring(x: np.ndarray, t: np.ndarray = TIME) -> dict[str, tuple[np.ndarray,
                                                                         np.ndarray]]:
    """``m a + c v + k p = F`` with the force ``F = 10 N`` times :func:`command`;
    x = (m [kg], c [N s/m], k [N/m]); signals "position" [m] and "acceleration"
    [m/s2]: two units two orders of magnitude apart."""
    m, c, k = (float(v) for v in x)
    a = np.array([[0.0, 1.0], [-k / m, -c / m]])
    b = np.array([[0.0], [1.0 / m]])
    out_c = np.array([[1.0, 0.0], [-k / m, -c / m]])
    out_d = np.array([[0.0], [1.0 / m]])
    y = held_response((a, b, out_c, out_d), 10.0 * command(t), t)
    return {"position": (t.copy(), y[:, 0]), "acceleration": (t.copy(), y[:, 1])}


#: (m, c, k) of the tests' mass-spring-damper.
SPRING_TRUE = np.array([2.0, 3.0, 200.0])
SPRING_PARAMETERS = (Parameter("m", 1.0, 0.2, 10.0), Parameter("c", 8.0, 0.1, 50.0),
                     Parameter("k", 150.0, 10.0, 1000.0))


class Counted:
    """A batched simulate over ``model`` that counts its batches and runs."""

    def __init__(self, model) -> None:  # type: ignore[no-untyped-def]
        self.model = model
        self.batches: list[int] = []

    def __call__(self, batch: list[np.ndarray]) -> list[dict[str, tuple[np.ndarray,
                                                                          np.ndarray]]]:
        self.batches.append(len(batch))
        return [self.model(x) for x in batch]


def data_of(model, truth: np.ndarray, noise: Mapping[str, float] | None = None,  # type: ignore[no-untyped-def]
            seed: int = 0, columns: Mapping[str, str] | None = None) -> MeasuredData:
    """``model`` at ``truth`` on :data:`TIME`, plus white noise of standard deviation
    ``noise[signal]`` (seeded); ``columns`` renames signals to columns."""
    rng = np.random.default_rng(seed)
    out = model(truth)
    cols = {}
    for signal, (_, values) in out.items():
        sd = (noise or {}).get(signal, 0.0)
        cols[(columns or {}).get(signal, signal)] = values + sd * rng.standard_normal(
            values.size)
    return measured_data(TIME, cols)
