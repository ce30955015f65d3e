"""Linear standing wave in a tank: period, amplitude and energy against linear theory.

Mode 1 of a tank of length L and depth d: k = pi / L, omega^2 = g k tanh(k d) (the dispersion relation), the
surface eta(x, t) = a cos(k (x - x0)) sin(omega t) exp(-2 nu k^2 t) (viscous decay of a free-surface wave,
Lamb 1932 s. 348). The run starts at the phase eta = 0 with the potential-flow velocity of that phase
(configs/standing_wave_2d.yaml). Elevations are read next to both walls (validation/elevation.py), relative to their
reading at the start (where theory gives eta = 0), above the tank's floor (a floor read from the lowest particles moves with the wave:
+1% of amplitude). In 3D (vertical z) the wave runs along x and is uniform across the tank: the elevation is read
at the tank's middle in y (the mean y of the fluid at the start; configs/standing_wave_3d.yaml).
"""

from __future__ import annotations

import math

import numpy as np

from taichi_sph.config.schema import Config, Metric
from taichi_sph.errors import ConfigError
from taichi_sph.validation.diagnostics import kinetic_energy
from taichi_sph.validation.elevation import surface_elevation
from taichi_sph.validation.energy import elastic_energy, potential_energy, rest_state
from taichi_sph.validation.metrics.base import MetricObserver, fluid_mask


def standing_wave_omega(length: float, depth: float, g: float) -> float:
    """omega = sqrt(g k tanh(k d)), k = pi / L (the first sloshing mode)."""
    k = math.pi / length
    return math.sqrt(g * k * math.tanh(k * depth))


def zero_crossings(t: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Times where y changes sign (linear interpolation between samples)."""
    s = np.sign(y)
    i = np.flatnonzero(s[:-1] * s[1:] < 0)
    return t[i] - y[i] * (t[i + 1] - t[i]) / (y[i + 1] - y[i])


def observed_period(t: np.ndarray, y: np.ndarray) -> float:
    """Twice the mean spacing of successive zero crossings (nan with fewer than two)."""
    z = zero_crossings(t, y)
    return float(2.0 * np.mean(np.diff(z))) if len(z) >= 2 else float("nan")


def kinetic_peak_trend(t: np.ndarray, kinetic: np.ndarray, period: float) -> float:
    """The wave's energy change a period from its kinetic energy at the peaks: every half period the surface passes
    through rest and the wave's energy is all kinetic. The kinetic energy's maximum within a quarter period around
    each k T / 2, then the least-squares slope of those maxima times T, relative to the first (nan with fewer than
    three). Unlike the energy above rest it does not see the fluid's mean level, which holds the potential energy of
    the whole column: in the 3D tank at 20 particles over the depth a level change of 0.017 mm (1.7e-5 of the
    volume) is 8% of a 2 cm wave's energy a period."""
    peaks = []
    for k in range(int(t[-1] / (period / 2)) + 1):
        near = np.flatnonzero(np.abs(t - k * period / 2) < period / 8)
        if len(near) > 2:
            i = near[np.argmax(kinetic[near])]
            peaks.append((t[i], kinetic[i]))
    if len(peaks) < 3 or peaks[0][1] <= 0.0:
        return float("nan")
    tp, kp = np.array(peaks).T
    return float(np.polyfit(tp, kp, 1)[0] * period / kp[0])


def kinetic_energy_period(t: np.ndarray, kinetic: np.ndarray, period: float) -> float:
    """The whole fluid's period from its kinetic energy, which a standing wave swings at twice its frequency:
    the least-squares fit K(t) = a + d t + b cos(2 omega t) + c sin(2 omega t) over the record, omega scanned
    within +-20% of 2 pi / period and refined around the best (nan for less than a period; a swing whose size
    drifts is fitted by its mean: a term linear in t times the swing would stand in for a frequency shift). Unlike
    the zero crossings of the elevation next to a wall it reads no probe: the contact line's own motion at the wall
    moves those (docs/wcsph.md, "The contact line's dry walls")."""
    if len(t) < 16 or t[-1] - t[0] < period:
        return float("nan")

    def residual(omega: float) -> float:
        c, s_ = np.cos(2.0 * omega * t), np.sin(2.0 * omega * t)
        basis = np.column_stack([np.ones_like(t), t, c, s_])
        coef = np.linalg.lstsq(basis, kinetic, rcond=None)[0]
        return float(np.sum((basis @ coef - kinetic) ** 2))

    omega0 = 2.0 * math.pi / period
    grid = omega0 * np.linspace(0.8, 1.2, 401)
    best = int(np.argmin([residual(w) for w in grid]))
    if best in (0, len(grid) - 1):
        return float("nan")  # no minimum inside the window
    fine = np.linspace(grid[best - 1], grid[best + 1], 201)
    omega = float(fine[int(np.argmin([residual(w) for w in fine]))])
    return 2.0 * math.pi / omega


class StandingWaveMetric(MetricObserver):
    """Errors of a standing wave (module docstring): period (the elevation's zero crossings next to the left wall, and
    the whole fluid's from its kinetic energy), amplitude after the run, energy per period (above rest, and the
    wave's own from its kinetic peaks), symmetry."""

    def __init__(self, cfg: Config, spec: Metric) -> None:
        super().__init__(cfg, spec)
        if spec.depth is None or spec.amplitude is None:
            raise ConfigError("a standing_wave metric needs 'depth' and 'amplitude'", key="metrics[].depth")
        g = float(np.linalg.norm(cfg.gravity_vector))
        self.k = math.pi / spec.width
        self.omega = standing_wave_omega(spec.width, spec.depth, g)
        self.decay = 2.0 * cfg.fluid.nu * self.k * self.k
        self.margin = 3.0 * cfg.particles.dx  # the elevation kernel's half-width: keep it inside the tank
        self.x_left = spec.origin + self.margin
        self.x_right = spec.origin + spec.width - self.margin
        self.rows: list[tuple[float, float, float, float]] = []
        self.rest = None
        self.offset: tuple[float, float] | None = None
        self.across: tuple[float, ...] = ()  # 3D: the y the elevations are read at

    def probe_point(self, x: float) -> tuple[float, ...]:
        """Where eta is read: x along the wave (and, in 3D, the tank's middle across it)."""
        return (x, *self.across)

    def columns(self) -> list[str]:
        return ["eta_left", "eta_right", "eta_theory_left"]

    def theory(self, x: float, t: float) -> float:
        return self.spec.amplitude * math.cos(self.k * (x - self.spec.origin)) * math.sin(self.omega * t) * math.exp(-self.decay * t)

    def observe(self, t: float, state: dict) -> dict:
        f = fluid_mask(state)
        x, v, m, rho = state["x"][f], state["v"][f], state["mass"][f], state["rho"][f]
        if self.rest is None:
            self.rest = rest_state(self.cfg, m, self.released)
            self.across = tuple(float(c) for c in x[:, 1:-1].mean(axis=0))
        left = surface_elevation(x, m / rho, self.probe_point(self.x_left), self.margin, floor=self.spec.floor)
        right = surface_elevation(x, m / rho, self.probe_point(self.x_right), self.margin, floor=self.spec.floor)
        if self.offset is None:  # the rest level (the surface row's volumes against dx^dim):
            self.offset = (left - self.theory(self.x_left, t), right - self.theory(self.x_right, t))
        left, right = left - self.offset[0], right - self.offset[1]
        kinetic = kinetic_energy(v, m)
        energy = (kinetic + potential_energy(self.cfg, x, m)
                  + elastic_energy(self.cfg, rho, m) - self.rest.potential - self.rest.elastic)
        self.rows.append((t, left, right, energy, kinetic))
        return {"eta_left": left, "eta_right": right, "eta_theory_left": self.theory(self.x_left, t)}

    def finish(self, state: dict) -> dict:
        if len(self.rows) < 8:
            return {"standing_wave_note": "run too short for the standing-wave metric"}
        t, left, right, energy, kinetic = (np.asarray(c) for c in zip(*self.rows))
        period = 2.0 * math.pi / self.omega
        p_left, p_right = observed_period(t, left), observed_period(t, -right)
        # amplitude over the last full period against the theory's envelope at the same times
        last = t >= t[-1] - period
        amp = 0.5 * (np.ptp(left[last]) + np.ptp(right[last])) / 2.0
        envelope = self.spec.amplitude * math.cos(self.k * self.margin) * math.exp(-self.decay * float(t[last].mean()))
        full = t[-1] - t[0] >= period
        # energy change per period: least-squares slope of E(t) over the run, relative to E(0)
        slope = float(np.polyfit(t, energy, 1)[0]) if len(t) > 2 else float("nan")
        return {"period_theory_s": period, "period_error": p_left / period - 1.0,
                "period_error_kinetic": kinetic_energy_period(t, kinetic, period) / period - 1.0,
                "period_asymmetry": abs(p_left - p_right) / period,
                "amplitude_ratio": float(amp / envelope) if full else float("nan"),
                "energy_change_per_period": slope * period / energy[0] if energy[0] > 0 else float("nan"),
                "wave_energy_change_per_period": kinetic_peak_trend(t, kinetic, period)}
