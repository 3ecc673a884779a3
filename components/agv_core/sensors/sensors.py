"""Sensors: vision (seed 000), robotic total station, fibre-optic gyro, steering angle (seed 004).

Timing semantics shared by the sampled sensors (vision, total station)
---------------------------------------------------------------------
The rule is the one of every sampled component (agv_core.numerics.sampling, components/README.md
"Sampling"); the sensors add latency and noise to it.
The master holds every input constant over a communication step [t, t + h). A sample
(camera frame, total-station fix) is *captured* at its instant t_k from the input held
at that instant: a capture instant belongs to the step [t, t + h) when
t - EPS <= t_k < t + h - EPS, with EPS = 1e-9 s, so an instant that coincides with a
communication point (within EPS) is captured from the inputs set at that point,
whatever the step size. The sample becomes the output at t_k + latency; after a step to
T the outputs hold the newest sample with t_k + latency <= T + EPS. Nothing needs the
step to divide the sampling period or the latency: both are exact to EPS.

Direct feedthrough: with zero latency a sample captured at a communication point T is
the output at T, computed from the inputs the master has just set at T (a tentative
sample, redrawn with the same random numbers until the step from T commits it). An
output that can do this for some parameter value depends on its input; the FMUs declare
it so (vision: all outputs on x, y, heading; total station: x_meas, y_meas on x, y;
gyro, steering sensor: always).

Before the first sample arrives (t0 <= T < t0 + latency) the outputs hold the noise-free
value of the pose at t0: the vehicle is assumed to have stood at its initial pose before
the start, so earlier frames saw it there.

Randomness: one ``numpy.random.default_rng(seed)`` per sensor; its
``bit_generator.state`` is part of ``get_state()``. Draw order per sample is fixed
(documented per class), so the same seed gives the same outputs. A tentative sample draws
its noise once per instant and keeps it (with the generator state from before the draw);
the step that commits the sample uses those numbers, and anything else (another instant,
a restored state) first puts the generator back: the stream is the one of drawing every
sample once, in order, however often the outputs are read. A sensor whose generator
feeds nothing but the samples' noise (vision) keeps the numbers instead of the state:
they are the next numbers of its stream whichever sample is committed next, so nothing
is put back, and its state holds them (``ahead``) with the generator's state after them.
A sensor without random spread (vision: both noise deviations 0; total station: noise
and jitter 0; gyro, steering sensor: noise 0) draws nothing: its samples are noise-free
and its generator stays at the seed's start. One with any spread draws every number of
its documented order, zero-weighted ones included, so the stream is the same whatever
the other parameters are.
"""

import math
from collections import deque
from collections.abc import Sequence
from typing import Any, cast

import numpy as np

from ..errors import ParameterError
from ..numerics.paths import PathProjection, ReferencePath, heading_error
from ..numerics.sampling import TIME_EPS, at_instant, in_step

#: Time tolerance [s] for matching sample instants to communication points: the one
#: tolerance of agv_core.numerics.sampling.
EPS = TIME_EPS

#: The values of one sample, in the sensor's documented order (also its noise).
Values = tuple[float, ...]


def _nonneg(name: str, value: float) -> float:
    if not (value >= 0.0 and math.isfinite(value)):
        raise ParameterError(name, f"must be finite and >= 0, got {value}")
    return float(value)


def _seed(seed: float) -> int:
    if int(seed) != seed or seed < 0:
        raise ParameterError("seed", f"must be a non-negative integer, got {seed}")
    return int(seed)


def _quantize(value: float, resolution: float) -> float:
    """Round ``value`` to the nearest multiple of ``resolution`` (none when 0)."""
    if resolution <= 0.0:
        return value
    return math.floor(value / resolution + 0.5) * resolution


class _Sampled:
    """Capture schedule, latency line and random generator of a sampled sensor."""

    def __init__(self, latency: float, seed: float, t0: float, draws: bool = True) -> None:
        self.latency = _nonneg("latency", latency)
        self.rng = np.random.default_rng(_seed(seed))
        #: False for a sensor without random spread: it never uses its generator
        self.draws = bool(draws)
        self.t0 = float(t0)
        #: (t_available, t_capture, values) of the samples captured and not yet shown
        self.pending: deque[tuple[float, float, Values]] = deque()
        #: (t_capture, values) of the newest available sample
        self.current: tuple[float, Values] | None = None
        self.initial: tuple[float, Values] | None = None
        #: (instant [s], generator state before the draw, noise) of a tentative sample
        #: (the generator's state is a mapping, None for a noise-only stream)
        self._drawn: tuple[float, Any, Values] | None = None
        #: False during a dropout: samples due then are drawn (so the random stream
        #: after the dropout is the same as without it) but lost, and the last one
        #: received stays shown
        self.available = True

    # hooks -----------------------------------------------------------------
    def _next_time(self) -> float:
        raise NotImplementedError

    def _advance_schedule(self) -> None:
        raise NotImplementedError

    def _noise(self) -> Values:
        """Draw the noise of one sample (a tuple, in the class's documented order)."""
        raise NotImplementedError

    def _sample(self, inputs: Sequence[float], noise: Values | None, commit: bool = False
                ) -> Values:
        """Sample values for ``inputs`` plus ``noise`` (None: noise-free); ``commit`` for
        a captured (not tentative) one."""
        raise NotImplementedError

    # noise -----------------------------------------------------------------
    #: True when the generator feeds only :meth:`_noise`, which draws the same numbers
    #: whatever the sample: kept numbers are then the next ones of the stream for
    #: whichever sample is committed next, and are kept instead of the generator state
    #: (reading that state costs more than the draws)
    NOISE_ONLY_STREAM = False

    def _tentative_noise(self, t_k: float) -> Values | None:
        """The noise of the sample of instant ``t_k``, drawn once and kept (None: the
        sensor draws nothing)."""
        if not self.draws:
            return None
        drawn = self._drawn
        if drawn is not None:
            if at_instant(drawn[0], t_k):
                return drawn[2]
            if self.NOISE_ONLY_STREAM:              # the next numbers, for any instant
                self._drawn = (t_k, None, drawn[2])
                return drawn[2]
            self.rng.bit_generator.state = drawn[1]   # drawn for another instant: undo
        state = None if self.NOISE_ONLY_STREAM else self.rng.bit_generator.state
        self._drawn = drawn = (t_k, state, self._noise())
        return drawn[2]

    def _undo_tentative(self) -> None:
        """Put back the numbers of a tentative sample that will not be committed next
        (a noise-only stream keeps them: they are its next numbers)."""
        if self._drawn is not None and not self.NOISE_ONLY_STREAM:
            self.rng.bit_generator.state = self._drawn[1]
            self._drawn = None

    # timing ----------------------------------------------------------------
    def _due(self, t: float) -> bool:
        return at_instant(self._next_time(), t)

    def step(self, t: float, h: float, *inputs: float) -> None:
        """Advance from ``t`` to ``t + h`` [s] with ``inputs`` held."""
        if self.initial is None:
            self.initial = (self.t0, self._sample(inputs, None))
        drawn = self._drawn
        if drawn is not None:
            # kept numbers are the next draws only for the first instant this step commits
            t_k = self._next_time()
            if not (at_instant(drawn[0], t_k) and in_step(t_k, t, h)):
                self._undo_tentative()
        end = t + h
        while self._next_time() < end - EPS:
            t_k = self._next_time()
            if in_step(t_k, t, h):  # agv_core.numerics.sampling's rule (instants before t: skipped)
                noise: Values | None
                drawn = self._drawn
                if drawn is not None:
                    self._drawn = None
                    noise = drawn[2]
                elif self.draws:
                    noise = self._noise()
                else:
                    noise = None
                values = self._sample(inputs, noise, commit=True)
                if self.available:
                    self.pending.append((t_k + self.latency, t_k, values))
            self._advance_schedule()
        while self.pending and self.pending[0][0] <= end + EPS:
            _, t_k, values = self.pending.popleft()
            self.current = (t_k, values)

    def output(self, t: float, *inputs: float) -> tuple[float, Values]:
        """(t_capture, values) the sensor shows at ``t`` [s] for the current inputs."""
        if self.available and self.latency <= EPS and self._due(t):
            # the step from t commits these same numbers
            return t, self._sample(inputs, self._tentative_noise(self._next_time()))
        if self.current is not None:
            return self.current
        if self.initial is not None:
            return self.initial
        return self.t0, self._sample(inputs, None)

    # state -----------------------------------------------------------------
    def get_state(self) -> dict[str, Any]:
        """JSON-safe snapshot of the internal state."""
        drawn, ahead = self._drawn, None
        if drawn is None or self.NOISE_ONLY_STREAM:
            rng = self.rng.bit_generator.state
            ahead = None if drawn is None else list(drawn[2])
        else:
            rng = drawn[1]
        return {"rng": rng, "ahead": ahead, "t0": self.t0,
                "pending": [[a, c, list(v)] for a, c, v in self.pending],
                "current": None if self.current is None else [self.current[0],
                                                              list(self.current[1])],
                "initial": None if self.initial is None else [self.initial[0],
                                                              list(self.initial[1])]}

    def set_state(self, state: dict[str, Any]) -> None:
        """Restore a snapshot from :meth:`get_state`."""
        self.rng.bit_generator.state = state["rng"]
        self.t0 = float(state["t0"])
        ahead = state.get("ahead")
        self._drawn = None if ahead is None else (math.nan, None, tuple(ahead))
        self.pending = deque((a, c, tuple(v)) for a, c, v in state["pending"])
        self.current = None if state["current"] is None else (state["current"][0],
                                                              tuple(state["current"][1]))
        self.initial = None if state["initial"] is None else (state["initial"][0],
                                                              tuple(state["initial"][1]))


class VisionSensor(_Sampled):
    """Camera measuring lateral deviation and heading error from a reference path.

    Parameters
    ----------
    path : agv_core.numerics.paths.ReferencePath
        The reference path.
    frame_period : float
        Capture period [s]; frames at multiples of it; 0 captures at every
        communication point. Default 0.04 s: a PAL camera's 25 frames/s.
    latency : float
        Image processing delay [s] from capture to output. Default 0.04 s: one frame
        time for a 1990s frame grabber plus PC to find the guide line.
    noise_lateral : float
        Standard deviation of the lateral-error noise [m]. Default 0.002 m: about one
        to two pixels of a 768-pixel PAL line seeing a ~1 m wide field.
    noise_heading : float
        Standard deviation of the heading-error noise [rad]. Default 0.004 rad: 2 mm
        over a ~0.5 m long visible line segment.
    seed : int
        Random seed (>= 0).
    t0 : float
        Start time [s].

    Notes
    -----
    Per frame the generator draws the lateral noise, then the heading noise (both, when
    either deviation is above 0; none when both are 0).
    ``s``, ``curvature`` and ``curvature_rate`` are those of the projection of the
    captured pose (noise-free); projections after the first use the previous frame's s
    as hint.
    """

    NOISE_ONLY_STREAM = True

    def __init__(self, path: ReferencePath, frame_period: float = 0.04, latency: float = 0.04,
                 noise_lateral: float = 0.002, noise_heading: float = 0.004, seed: int = 0,
                 t0: float = 0.0) -> None:
        self.path = path
        self.frame_period = _nonneg("frame_period", frame_period)
        self.noise_lateral = _nonneg("noise_lateral", noise_lateral)
        self.noise_heading = _nonneg("noise_heading", noise_heading)
        super().__init__(latency, seed, t0,
                         draws=self.noise_lateral > 0.0 or self.noise_heading > 0.0)
        p = self.frame_period
        self.next_k = 0 if p == 0.0 else math.ceil((self.t0 - EPS) / p)
        self.next_t = self.t0
        self.s_hint: float | None = None
        self._projected: tuple[float | None, float | None, float | None,
                               PathProjection | None]
        self._projected = (None, None, None, None)  # x, y, s_hint, projection of the last

    def _next_time(self) -> float:
        return self.next_t if self.frame_period == 0.0 else self.next_k * self.frame_period

    def _advance_schedule(self) -> None:
        if self.frame_period == 0.0:
            self.next_t = math.inf      # one capture per step; step() sets the next one
        else:
            self.next_k += 1

    # the pose is _Sampled.step's inputs
    def step(self, t: float, h: float, x: float, y: float,  # type: ignore[override]
             heading: float) -> None:
        """Advance from ``t`` to ``t + h`` [s] with the pose held."""
        if self.frame_period == 0.0:
            self.next_t = t
            super().step(t, h, x, y, heading)
            self.next_t = t + h
        else:
            super().step(t, h, x, y, heading)

    def _noise(self) -> tuple[float, float]:
        normal = self.rng.standard_normal
        lateral = self.noise_lateral * normal()
        return lateral, self.noise_heading * normal()

    def _sample(self, inputs: Sequence[float], noise: Values | None, commit: bool = False
                ) -> tuple[float, float, float, float, float]:
        x, y, heading = inputs
        # a tentative sample and its commit project the same pose (the very same float
        # objects, so the same values and signs of zero): project once
        hint = self.s_hint
        px, py, ph, p = self._projected
        if not (x is px and y is py and hint is ph):
            p = self.path.project(x, y, hint)
            self._projected = (x, y, hint, p)
        p = cast(PathProjection, p)  # kept for this very pose, or new
        if commit:
            self.s_hint = p.s
        lateral, head = p.offset, heading_error(heading, p.heading)
        if noise is not None:
            lateral += noise[0]
            head += noise[1]
        return (lateral, head, p.s, p.curvature, p.curvature_rate)

    def measure(self, t: float, x: float, y: float, heading: float) -> Values:
        """Outputs at ``t`` [s]: (lateral_error [m], heading_error [rad], s [m],
        curvature [1/m], curvature_rate [1/m^2])."""
        return self.output(t, x, y, heading)[1]

    def get_state(self) -> dict[str, Any]:
        state = super().get_state()
        state.update(next_k=self.next_k, next_t=self.next_t, s_hint=self.s_hint)
        return state

    def set_state(self, state: dict[str, Any]) -> None:
        super().set_state(state)
        self.next_k, self.next_t, self.s_hint = state["next_k"], state["next_t"], \
            state["s_hint"]


class TotalStation(_Sampled):
    """Robotic total station: position fixes at jittered intervals, sent with latency.

    Parameters
    ----------
    mean_interval : float
        Mean time between fixes [s] (> 0). Default 0.65 s (seed 004).
    jitter : float
        Each interval is ``mean_interval + U(-jitter, +jitter)`` [s], < mean_interval.
        Default 0.15 s (tracking-mode update times of a robotic station vary by a few
        tenths of a second; the paper gives only the mean).
    latency : float
        Radio-modem transmission delay [s]. Default 0.1 s.
    noise : float
        Standard deviation of each coordinate's noise [m]. Default 0.003 m (mm-level,
        a few mm for a moving prism).
    seed : int
        Random seed (>= 0).
    t0 : float
        Start time [s]; the first fix is captured at t0.

    Notes
    -----
    Per fix the generator draws the x noise, the y noise, then the next interval (all
    three when the noise or the jitter is above 0, so the fix times of a noise-free
    station with jitter are those of a noisy one; none when both are 0).
    """

    def __init__(self, mean_interval: float = 0.65, jitter: float = 0.15, latency: float = 0.1,
                 noise: float = 0.003, seed: int = 0, t0: float = 0.0) -> None:
        if not (mean_interval > 0.0 and math.isfinite(mean_interval)):
            raise ParameterError("mean_interval", f"must be positive, got {mean_interval}")
        self.mean_interval = float(mean_interval)
        self.jitter = _nonneg("jitter", jitter)
        if self.jitter >= self.mean_interval:
            raise ParameterError("jitter", f"must be < mean_interval ({mean_interval} s), "
                                           f"got {jitter}")
        self.noise = _nonneg("noise", noise)
        super().__init__(latency, seed, t0, draws=self.noise > 0.0 or self.jitter > 0.0)
        self.next_t = self.t0

    def _next_time(self) -> float:
        return self.next_t

    def _advance_schedule(self) -> None:
        if self.draws:
            self.next_t += self.mean_interval + self.jitter * (2.0 * self.rng.random() - 1.0)
        else:
            self.next_t += self.mean_interval

    def _noise(self) -> tuple[float, float]:
        normal = self.rng.standard_normal
        nx = self.noise * normal()
        return nx, self.noise * normal()

    def _sample(self, inputs: Sequence[float], noise: Values | None, commit: bool = False
                ) -> tuple[float, float]:
        x, y = inputs
        if noise is not None:
            x += noise[0]
            y += noise[1]
        return (x, y)

    def measure(self, t: float, x: float, y: float) -> tuple[float, float, float]:
        """Outputs at ``t`` [s]: (x_meas [m], y_meas [m], fix_age [s]).

        ``fix_age`` is ``t`` minus the capture time of the fix shown.
        """
        t_k, (xm, ym) = self.output(t, x, y)
        return xm, ym, max(t - t_k, 0.0)

    def get_state(self) -> dict[str, Any]:
        state = super().get_state()
        state["next_t"] = self.next_t
        return state

    def set_state(self, state: dict[str, Any]) -> None:
        super().set_state(state)
        self.next_t = state["next_t"]


class InstantSensor:
    """Sensor sampled at every communication point: drift, noise, quantisation.

    measured = quantize(true + drift (t - t0) + noise, resolution)

    Parameters
    ----------
    drift : float
        Drift rate of the reading [unit/s] (gyro: 0.5 deg/h = 2.4241e-6 rad/s).
    noise : float
        Standard deviation of white noise per sample [unit].
    resolution : float
        Quantisation step [unit]; 0 for none.
    seed : int
        Random seed (>= 0).
    t0 : float
        Start time [s].

    Notes
    -----
    The sample at a communication point t uses the generator's next normal draw; the
    reading shown at t (for the inputs set at t) is redrawn identically until the step
    from t commits the draw, so repeated reads give the same value.
    """

    def __init__(self, drift: float = 0.0, noise: float = 0.0, resolution: float = 0.0,
                 seed: int = 0, t0: float = 0.0) -> None:
        if not math.isfinite(drift):
            raise ParameterError("drift", f"must be finite, got {drift}")
        self.drift = float(drift)
        self.noise = _nonneg("noise", noise)
        self.resolution = _nonneg("resolution", resolution)
        self.rng = np.random.default_rng(_seed(seed))
        self.t0 = float(t0)
        #: the next normal draw, taken by a reading and not yet committed by a step
        self._next_normal: float | None = None

    def measure(self, t: float, value: float) -> float:
        """Reading at ``t`` [s] of the true ``value`` (the draw is committed by the step)."""
        noise = 0.0
        if self.noise > 0.0:
            if self._next_normal is None:
                self._next_normal = self.rng.standard_normal()
            noise = self.noise * self._next_normal
        return _quantize(value + self.drift * (t - self.t0) + noise, self.resolution)

    def step(self, t: float, h: float) -> None:
        """Commit the sample taken at ``t`` and move on to ``t + h`` [s]."""
        if self.noise > 0.0:
            if self._next_normal is None:
                self.rng.standard_normal()
            self._next_normal = None

    def get_state(self) -> dict[str, Any]:
        """JSON-safe snapshot of the internal state (a draw a reading took is kept)."""
        return {"rng": self.rng.bit_generator.state, "next_normal": self._next_normal,
                "t0": self.t0}

    def set_state(self, state: dict[str, Any]) -> None:
        """Restore a snapshot from :meth:`get_state`."""
        self.rng.bit_generator.state = state["rng"]
        self._next_normal = state.get("next_normal")
        self.t0 = float(state["t0"])


#: Defaults of the seed-004 fibre-optic gyro: drift 0.5 deg/h, resolution 0.01 deg.
GYRO_DRIFT = math.radians(0.5) / 3600.0
GYRO_RESOLUTION = math.radians(0.01)
#: Defaults of the steering-angle (displacement) sensor: noise 0.001 rad, resolution 0.1 deg
#: written to 13 digits (0.001745329251994; math.radians(0.1) differs in the last ones, and
#: the committed results use this value).
STEER_NOISE = 0.001
STEER_RESOLUTION = 0.001745329251994
