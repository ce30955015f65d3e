"""Configuration: YAML (+ `extends:`) -> overrides -> validated, frozen dataclasses.

Every key, its default, unit and allowed values is declared once, here, in the dataclass
fields' metadata; `taichi-sph config-doc` prints the reference (docs/config_reference.md).
Every refusal is a ConfigError naming the file, the key and what is allowed.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any

AUTO = "auto"
# ISPH's Monaghan viscosity acts on every pair, WCSPH's on approaching pairs: the shared alpha halved gives ISPH
# the same shear viscosity (Config.artificial_viscosity)
ISPH_SHARED_ALPHA_FACTOR = 0.5
# A of the particle shift when a scene sets none (shifting.coefficient); the shift WCSPH turns on itself in a fluid
# that fills its container takes scene/confinement.py's CONFINED_SHIFT_COEFFICIENT
SHIFTING_COEFFICIENT = 2.0

# h / dx when a scene does not set particles.hdx. WCSPH, 2.0 (~50 neighbours in 2D): at 1.3 (~21) a standing wave
# with no diffusion and no shifting turned its lattice into noise within half a period (kinetic energy 2 -> 5 J,
# period -6%, amplitude 0.64 of theory after 3 periods); at 2.0 it keeps it (period -1.2%, amplitude 1.01,
# energy -0.3% a period: standing_wave_2d at dx 0.025). ISPH, by dimension: its summation density (the
# density-invariance source) pairs at h = 2 dx on the stretching drop (0.13 dx, a void), and reads an arrangement's
# disorder as compression the more the fewer neighbours it has, so the projection expands a disordered fluid. In 2D
# h = 1.3 dx (~21 neighbours) is too few once a splash disorders the fluid: a drop into a pool (docs/notes/
# drop_into_pool_2d.yaml) gained energy from t = 0.65 s and ended "unstable" at 0.9 s, and a 4 cm standing wave at
# 2.8 s; 1.5 dx (~28) runs both (to 1.2 s; wave ok over 3 periods) and keeps the 2 cm wave within issue 23's targets
# at 40 and 80 particles over the depth (1.4: pool "unstable" at 1.0 s; 1.6: the 2 cm wave +2.6% energy a period;
# session 26, docs/isph.md). In 3D 1.3 dx already gives ~74 neighbours (the 3D wave at 1.5: amplitude 0.974 but its
# volume drifts, -17% of the wave's energy a period).
DEFAULT_HDX = {"wcsph": {1: 2.0, 2: 2.0, 3: 2.0}, "isph": {1: 1.3, 2: 1.5, 3: 1.3}}
# WCSPH's h / dx on a hexagonal packing: Wendland C2's hexagonal lattice sum is isotropic and its shear stiffness
# crosses zero near 2.08 dx (scene/lattice.py lattice_shear_stiffness): 2.1 keeps it small and positive (+0.0075
# against the square lattice's +0.026 at 2.0); at 2.0 (-0.036) the lattice rearranges into noise (docs/wcsph.md)
HEXAGONAL_HDX = 2.1
# the kernels a scene may choose, with their support radius / h (sph/kernels.py builds them)
KERNEL_SUPPORT = {"cubic_spline": 2.0, "wendland_c2": 2.0, "wendland_c4": 2.0, "quintic_spline": 3.0, "gaussian": 3.0,
                  "poly6_spiky": 2.0}


def opt(default: Any = dataclasses.MISSING, doc: str = "", *, unit: str = "", choices: tuple | None = None,
        minimum: float | None = None, positive: bool = False, factory: Any = None) -> Any:
    """A documented config key: default, doc string, unit, allowed values and bounds."""
    meta = dict(doc=doc, unit=unit, choices=choices, minimum=minimum, positive=positive)
    if factory is not None:
        return field(default_factory=factory, metadata=meta)
    return field(default=default, metadata=meta)


# ----------------------------------------------------------------------------- schema
@dataclass(frozen=True)
class Domain:
    lo: tuple[float, ...] = opt((0.0, 0.0), "lower corner of the simulation domain; particles leaving it make the run unstable", unit="m")
    hi: tuple[float, ...] = opt((1.0, 1.0), "upper corner of the simulation domain", unit="m")
    periodic: tuple[bool, ...] | None = opt(None, "per-axis periodicity (list of dim booleans); default none periodic")


@dataclass(frozen=True)
class Particles:
    dx: float = opt(0.02, "initial particle spacing", unit="m", positive=True)
    hdx: float | None = opt(None, "smoothing length over spacing, h = hdx * dx; None = the solver's default "
                                  "(DEFAULT_HDX: 2.0 for WCSPH, 2.1 on a hexagonal packing with Wendland C2; ISPH 1.5 in 2D, 1.3 in "
                                  "1D and 3D)",
                              positive=True)
    kernel: str = opt("wendland_c2", "smoothing kernel", choices=tuple(KERNEL_SUPPORT))
    max_neighbors: int | str = opt(AUTO, "capacity of each particle's neighbour list ('auto': 2.5x the lattice count)")
    skin: float | str = opt(AUTO, "Verlet skin as a fraction of the support radius: lists cover support x (1 + skin) and "
                                  "are rebuilt only when a particle may have moved skin/2; 'auto' = 0.15 for WCSPH, "
                                  "0 (rebuild every step) for ISPH")
    packing: str = opt("square", "how fluid bodies are filled: 'square' (a square/cubic lattice, spacing dx) or "
                                 "'hexagonal' (2D: rows of a hexagonal lattice with dx^2 per particle, each box's rows "
                                 "and columns fitted to its size; scene/lattice.py hexagonal_box). Under a hydrostatic "
                                 "pressure a square lattice resists shear like a solid and a wall of the same lattice "
                                 "pins the fluid sliding along it: WCSPH's standing wave runs -1.3% fast at 40 particles "
                                 "over the depth. Hexagonal (WCSPH's h 2.1 dx, walls at dx / 2, with particles.settle "
                                 "0.6): -0.27%, the wave's targets met but its kinetic peaks' (+0.58% a period), but a "
                                 "tank at rest reads its pressure 6x worse (2.6% against 0.42%, physical keys only: "
                                 "the rows' staggered ends at the side walls); not the default (docs/wcsph.md, 'A "
                                 "hexagonal packing')",
                       choices=("square", "hexagonal"))
    settle: float = opt(0.0, "WCSPH (ISPH starts as packed): seconds of settling before t = 0 (run/settle.py): the scene run at rest (fluid "
                             "velocities zero, Monaghan alpha 0.5, the same gravity and walls), then its settled "
                             "positions and densities start the run with the bodies' velocities evaluated there. A "
                             "hexagonal packing's start is not the discrete equilibrium (its rows end staggered at "
                             "side walls): unsettled, the standing wave sheds ~1 J in its first period; after 0.6 s "
                             "of settling its energy above rest holds (docs/wcsph.md). 0 = none (a square lattice "
                             "starts in equilibrium)", unit="s", minimum=0.0)
    neighbor_access: str = opt("lists", "how pair loops reach neighbours: 'lists' = a stored Verlet list per particle "
                                        "(max_neighbors i32 each); 'cells' = a walk over the 3^dim cells around the "
                                        "particle in the cell-sorted arrays, no lists stored (WCSPH only; same sums "
                                        "in the same order, more candidates tested)", choices=("lists", "cells"))


@dataclass(frozen=True)
class Fluid:
    rho0: float = opt(1000.0, "rest density", unit="kg/m^3", positive=True)
    c0: float | str = opt(AUTO, "artificial sound speed (WCSPH); 'auto' = c0_factor x the larger of reference_speed and "
                                "sqrt(|g| L), L the fluid's extent along gravity (Morris, Fox & Zhu 1997: the body "
                                "force's pressure over the fluid, as compressible as the flow's)", unit="m/s")
    c0_factor: float = opt(10.0, "c0 / reference_speed when c0 is 'auto' (10 keeps density errors near 1%)", positive=True)
    reference_speed: float | None = opt(None, "the largest flow speed the scene expects, e.g. sqrt(2 g H) for a dam break", unit="m/s", positive=True)
    gamma: float = opt(7.0, "Tait exponent, p = B((rho/rho0)^gamma - 1), B = c0^2 rho0 / gamma", positive=True)
    nu: float = opt(0.0, "kinematic viscosity (laminar, Morris et al. 1997 form); 0 compiles it out", unit="m^2/s", minimum=0.0)
    laplacian: str = opt("morris", "the laminar viscosity's Laplacian: Morris et al. (1997) as it is, or 'normalised': divided by "
                                   "its lattice sum (scene/lattice.py lattice_gradient_sum, as ISPH's PPE), so that it is exact "
                                   "for a quadratic velocity on the lattice at any h / dx (quintic at h = dx: the plain form is "
                                   "0.6% low, a decay-rate error that no resolution removes), or 'renormalised': WCSPH only, over each "
                                   "particle's own second moment (physics/momentum.py renormalised_laplacian; ISPH takes "
                                   "'normalised' for it), or 'consistent': WCSPH only, 'renormalised' of the velocity "
                                   "differences less their linear part <grad v>_a r_ab (an extra pass for the renormalised "
                                   "velocity gradient; physics/momentum.py consistent_velocity_difference; Fatehi & "
                                   "Manzari 2011): no first-order error on a disordered arrangement (ISPH takes 'normalised')",
                          choices=("morris", "normalised", "renormalised", "consistent"))
    background_pressure: float = opt(0.0, "constant added to the equation of state (p_b); keeps pressure positive in closed "
                                          "flows; for ISPH the ambient pressure at a free surface and the mean pressure "
                                          "in closed boxes", unit="Pa", minimum=0.0)


@dataclass(frozen=True)
class Motion:
    amplitude: tuple[float, ...] = opt((), "the oscillation's amplitude along each axis (dim numbers): the body's "
                                           "displacement d(t) = r(t) A sin(2 pi t / T)", unit="m")
    period: float = opt(1.0, "the oscillation's period T", unit="s", positive=True)
    ramp: float | str = opt(AUTO, "r(t) = (1 - cos(pi t / t_ramp)) / 2 for t < t_ramp, then 1: the motion starts "
                                  "from rest without a jerk; 'auto' = one period, 0 = none", unit="s")


@dataclass(frozen=True)
class Body:
    type: str = opt("fluid_block", "what the body is", choices=("fluid_block", "fluid_sphere", "wall_box", "wall_block"))
    lo: tuple[float, ...] | None = opt(None, "box lower corner (fluid_block, wall_block; inner lower corner of wall_box)", unit="m")
    hi: tuple[float, ...] | None = opt(None, "box upper corner (inner upper corner of wall_box)", unit="m")
    center: tuple[float, ...] | None = opt(None, "fluid_sphere centre (a circle in 2D, a segment in 1D)", unit="m")
    radius: float | None = opt(None, "fluid_sphere radius", unit="m", positive=True)
    layers: int | None = opt(None, "wall_box: number of particle layers outside the inner box; None = as many as the kernel "
                                   "support spans, ceil(support / dx) (4 for WCSPH's default h = 2 dx, 3 for ISPH's 1.3 dx)",
                              minimum=1)
    open_top: bool = opt(True, "wall_box: no wall on the top face (highest axis)")
    velocity: tuple[Any, ...] | None = opt(None, "initial velocity (fluid) or prescribed velocity (wall): dim numbers, or dim "
                                           "expressions of x, y, z, t-free (numpy functions sin, cos, exp, sqrt, pi, ...)", unit="m/s")
    motion: Motion | None = opt(None, "wall_box/wall_block: a prescribed oscillation of the whole body (a piston wave "
                                     "maker, a shaken tank): its particles, faces, velocity and acceleration "
                                     "follow d(t) = r(t) A sin(2 pi t / T) (physics/walls.py oscillating_wall)")
    hydrostatic: bool = opt(False, "fluid_block/fluid_sphere: start with hydrostatic density for the given gravity (free surface at the body top)")
    pressure: Any = opt(None, "fluid: initial pressure, a number or an expression of x, y, z (as velocity, plus "
                                             "square_poisson(x, y, L): lap phi = 1 in the square |x|, |y| < L/2, 0 on its edges); "
                                             "WCSPH starts from the Tait density of it (no start-up pressure wave); None = 0 "
                                             "(or hydrostatic)", unit="Pa")


@dataclass(frozen=True)
class CentralForce:
    omega: float = opt(0.0, "a body force -omega^2 (x - center) toward a point, as a harmonic potential (holds a drop "
                            "together without walls, Monaghan & Rafiee 2013); 0 compiles it out", unit="1/s", minimum=0.0)
    center: tuple[float, ...] | None = opt(None, "the point the central force pulls toward; None = the domain centre", unit="m")


@dataclass(frozen=True)
class Reflecting:
    enabled: bool = opt(False, "reflect particles at the non-periodic domain faces (simple elastic floor/walls)")
    restitution: float = opt(1.0, "normal velocity kept after a reflection, 0..1", minimum=0.0)


@dataclass(frozen=True)
class DensityDiffusion:
    model: str = opt("none", "delta-SPH density diffusion: Molteni & Colagrossi 2009, with the hydrostatic part "
                              "removed (Fourtakas et al. 2019; the Tait column's difference at the pair's own depth), "
                              "or with the linear part of every pair's difference removed "
                              "through the renormalised density gradient (Antuono et al. 2010): zero on any linear density "
                              "field, also where a free surface cuts the kernel", choices=("none", "molteni", "fourtakas",
                                                                                           "antuono"))
    delta: float = opt(0.1, "diffusion coefficient delta", minimum=0.0)


@dataclass(frozen=True)
class ArtificialViscosity:
    alpha: float = opt(0.0, "Monaghan (1992) linear coefficient. WCSPH applies it to approaching pairs, ISPH's predictor "
                            "to every pair (an incompressible flow's approaching pairs recede along another axis) with "
                            "half this alpha (isph.artificial_viscosity_alpha unset): the same shear viscosity, as the "
                            "switched form's stress comes from half the pairs; 0 (with beta 0 and no switch) compiles "
                            "it out", minimum=0.0)
    beta: float = opt(0.0, "Monaghan quadratic coefficient", minimum=0.0)
    switch: str = opt(AUTO, "'morris_monaghan': each particle's alpha rises with its compression rate and decays "
                            "back to alpha (Morris & Monaghan 1997): d alpha_a / dt = -(alpha_a - alpha) / tau + "
                            "max(-div v_a, 0) (alpha_max - alpha_a), tau = h / (decay c0), pairs take the mean "
                            "(physics/momentum.py morris_monaghan_alpha): dissipation at an impact that a wave does "
                            "not get (a drop into a pool with the defaults: both solvers 'unstable' without it; with "
                            "it WCSPH ok, ISPH ok to t = 0.6 s; Buchner's WCSPH wall pressure RMS 0.23-0.51 over three "
                            "starts without it, 0.23-0.27 with; docs/wcsph.md). 'auto' = on "
                            "under gravity (not along a periodic axis: a driven channel has no impact), off "
                            "otherwise", choices=(AUTO, "none", "morris_monaghan"))
    alpha_max: float = opt(0.05, "the switch's ceiling (ISPH's dam_break_buchner_2d with 0.1: 'unstable' in 1 of 3 "
                                 "perturbed starts, with 0.05 ok in all); at or below the run's alpha the switch is off",
                           minimum=0.0)
    decay: float = opt(0.1, "the switch's decay rate in units of c0 / h", positive=True)


@dataclass(frozen=True)
class TensileCorrection:
    enabled: bool = opt(False, "Monaghan (2000) artificial pressure against the tensile instability")
    epsilon: float = opt(0.2, "strength: R = epsilon |p| / rho^2 for negative pressures", minimum=0.0)
    epsilon_positive: float = opt(0.0, "R = this x p / rho^2 for positive pressures (Monaghan 2000 and PySPH / DualSPHysics "
                                       "take 0.01). Off: it does not separate the pairs the dam break forms at its walls "
                                       "(dx a/40 to t = 0.7 s: closest 0.016 dx either way) and let 1 particle through the "
                                       "floor where 0 (with the wall mirror) let none", minimum=0.0)
    n: float = opt(4.0, "exponent of f = W(r)/W(dx)", positive=True)


@dataclass(frozen=True)
class Shifting:
    enabled: bool | None = opt(None, "particle shifting (Lind et al. 2012 form, free-surface aware); None = on for ISPH; for "
                                     "WCSPH on where the fluid fills its container (no free surface at the start, hence "
                                     "none in the run: scene/confinement.py) and the scene does not take the transport "
                                     "velocity, off otherwise (a shift moves a dam break's front ahead and feeds a wave: "
                                     "docs/wcsph.md)")
    model: str = opt("skillen", "the speed in the diffusion coefficient D = A h U dt: the particle's own |v_a| (Skillen et al. "
                                "2013; vanishes at stagnation points, where a stretched lattice then stays as it is) or the "
                                "largest fluid speed of the step (Sun et al. 2017, delta+-SPH: CFL Ma (2h)^2 = 4 h U dt)",
                     choices=("skillen", "sun"))
    coefficient: float | None = opt(None, "A in the shift dr_a = -D grad C_a with D = A h U dt (U: see shifting.model); "
                                          "None = 2, or 20 for the shift WCSPH turns on itself in a fluid that fills its "
                                          "container (`enabled` unset: the lid-driven cavity's and the Taylor-Green "
                                          "vortex's A; a channel past an obstacle keeps its wake's particles apart with "
                                          "it, docs/wcsph.md)", minimum=0.0)
    max_shift: float = opt(0.1, "cap on |dr_a| per step, as a fraction of dx", positive=True)
    walls: str = opt(AUTO, "what grad C sees of a container wall (wall_box): its wall particles, or 'mirror', the images "
                           "of the fluid in the faces the support meets: a free-slip wall is the fluid's mirror, and the "
                           "images slide with the fluid. 'auto' = mirror for ISPH (it needs the kinematic wall condition's "
                           "faces: particles when isph.wall_clearance is null), particles for WCSPH (its cavity is "
                           "better with them: 0.0047 / 0.0069 against 0.0077 / 0.0077). On the standing wave the wall "
                           "particles' part (it depends on how a sliding fluid row sits against the wall rows) was "
                           "ISPH's whole energy gain, +1.6% a period, mirror +0.2% (docs/isph.md). Other walls "
                           "(wall_block) always use their particles", choices=(AUTO, "particles", "mirror"))
    velocity_correction: bool = opt(False, "Taylor correction after the shift: v_a += (grad v)_a . dr_a, with the renormalised "
                                           "gradient (physics/shifting.py taylor_correction; Xu, Stansby & Laurence 2009, Lind "
                                           "et al. 2012). Without it a shifted particle keeps the velocity of the point it left")
    density: str = opt("fixed", "what WCSPH's continuity density does when a particle is shifted: 'continuity' "
                                "drho_a = sum_b m_b (dr_a - dr_b) . grad_a W_ab, the continuity equation with the "
                                "shift's displacements for v dt (walls do not shift), so the volumes m / rho follow the "
                                "arrangement and a shift changes the energy by -sum m_a a_a . dr_a, nothing at rest "
                                "(physics/density.py continuity_rate); 'taylor' rho_a += (grad rho)_a . dr_a (the "
                                "field carried to the new position; its volumes do not follow); 'fixed' keeps it. "
                                "With 'fixed' or 'taylor' the shift lifts a free surface: a standing wave gains ~9% of "
                                "its energy a period, 'continuity' ~0.4%. But with 'continuity' a strong shift becomes "
                                "a pressure pulse: dam_break_2d with shifting on (skillen A 4) 'unstable' at t = 0.51 s "
                                "where the surface meets the wall, cavity_2d (A 20) at 1 s, taylor_green_2d L1 0.24 "
                                "against 0.0043; so 'fixed' stays the default (docs/wcsph.md). ISPH and summation "
                                "density: not used", choices=("continuity", "taylor", "fixed"))


@dataclass(frozen=True)
class Walls:
    slip: str = opt("no_slip", "wall condition for the laminar viscosity (no_slip: Adami et al. 2012's extrapolated "
                                "ghost velocity 2 v_w - v_fluid; free_slip: no wall pairs). The artificial viscosity "
                                "sees a wall's own velocity either way (see walls.artificial_viscosity)",
                    choices=("no_slip", "free_slip"))
    artificial_viscosity: str = opt("relative", "what a wall particle shows a fluid particle in Monaghan's artificial "
                                              "viscosity at a free-slip wall: 'relative', the whole v_a - v_w, whose part "
                                              "along the wall is a friction on fluid sliding along it (the laminar "
                                              "viscosity has none at a free-slip wall); 'normal', its part along the wall "
                                              "face's normal only (physics/walls.py free_slip_relative_velocity): no "
                                              "tangential stress, approach still resisted. dam_break_2d WCSPH / ISPH "
                                              "front RMS raw / shifted 0.244 / 0.0398, 0.241 / 0.0424 -> 0.309 / 0.0349, "
                                              "0.312 / 0.0365; Buchner's WCSPH probe p* RMS / impact t* 0.289 / 2.63 -> "
                                              "0.201 / 2.61 (experiment 2.51); "
                                              "not the default yet (the front's raw target, ISPH's Buchner run: "
                                              "docs/notes/dam_break.md). Faces from wall_box and wall_block bodies; "
                                              "free_slip only", choices=("relative", "normal"))
    refinement: int | str = opt(AUTO, "wall particles r times finer than the fluid's (spacing dx / r, the same wall "
                                      "thickness, volume (dx / r)^dim each): fluid sliding along a wall feels the wall "
                                      "lattice's ripple with period dx / r, and a hexagonal fluid's rows meet a wall face "
                                      "at staggered distances that a wall at dx rattles (noise). 'auto' = 2 for WCSPH on "
                                      "a hexagonal packing, 1 otherwise (more than 1 is WCSPH's only: ISPH's wall rows "
                                      "assume 1)")


@dataclass(frozen=True)
class WCSPH:
    density: str = opt("continuity", "density evolution", choices=("continuity", "summation"))
    integrator: str = opt("symplectic_euler", "time integrator", choices=("symplectic_euler", "leapfrog"))
    density_diffusion: DensityDiffusion = opt(factory=DensityDiffusion, doc="delta-SPH term")
    artificial_viscosity: ArtificialViscosity = opt(factory=ArtificialViscosity, doc="Monaghan artificial viscosity")
    tensile_correction: TensileCorrection = opt(factory=TensileCorrection, doc="Monaghan tensile correction")
    clamp_negative_pressure: bool = opt(False, "clamp p >= 0 (free-surface flows with summation density)")
    pressure_gradient: str = opt("symmetric", "pressure gradient: the momentum-conserving symmetric form, or 'corrected': "
                                              "-(1/rho_a) L_a sum_b V_b (p_b - p_a) grad_a W_ab with the renormalisation "
                                              "matrix L_a (Bonet & Lok 1999), exact for a linear pressure on any arrangement "
                                              "(no zeroth-order error from the background pressure on a disordered one; not "
                                              "momentum-conserving; physics/momentum.py corrected_pressure_gradient), or "
                                              "'corrected_symmetric': -(1/rho_a) sum_b V_b (p_a L_a + p_b L_b) grad_a W_ab "
                                              "with the continuity divergence corrected by the same L_a, an energy-"
                                              "consistent pair (physics/momentum.py corrected_symmetric_pressure_gradient; "
                                              "experimental: the standing wave's period +0.02% but -2.1% of its energy a period at "
                                              "dx 0.025, -23% at 0.05; docs/wcsph.md)",
                                 choices=("symmetric", "corrected", "corrected_symmetric"))
    tensile_instability_control: bool = opt(False, "delta+-SPH's tensile instability control (Sun et al. 2017): a particle "
                                                   "in tension (p_a < 0) away from the free surface takes the pressure "
                                                   "gradient in the difference form (p_b - p_a), which has no pairwise "
                                                   "attraction; needs `shifting.model: sun` (its free-surface region)")
    gradient_normalisation: str = opt("lattice", "'lattice': the symmetric pressure gradient and the continuity divergence "
                                                 "divided by their sum for a linear field on the lattice, (1/dim) sum_b V_b "
                                                 "r_ab |dW/dr| (scene/lattice.py lattice_gradient_sum, as ISPH's PPE), so "
                                                 "that both are exact for a linear field on the rest lattice: the pressure "
                                                 "that holds a fluid against gravity is rho g d, not rho g d / sum "
                                                 "(Wendland C2: sum 0.974 at h = 1.3 dx, 0.9992 at 2 dx in 2D); 'none': "
                                                 "the plain kernel gradient. Both halves scaled alike keep the pressure's "
                                                 "work equal to the energy the density stores", choices=("lattice", "none"))
    surface_pressure_gradient: str = opt("symmetric", "symmetric: -sum_b m_b (p_a / rho_a^2 + p_b / rho_b^2) grad W_ab; "
                                                      "kernel_sum_scaled: the same with p / (S / S_lattice) in place of p "
                                                      "where the kernel sum S is deficient (the free-surface band): the "
                                                      "symmetric form approximates grad(p S) / rho there, so this one "
                                                      "grad p / rho, still pairwise antisymmetric "
                                                      "(physics/momentum.py kernel_sum_scaled_pressure)",
                                         choices=("symmetric", "kernel_sum_scaled"))
    surface_scale_floor: float = opt(0.5, "kernel_sum_scaled: S / S_lattice is floored at this (a flat surface's top row has "
                                          "0.65 at h = 2 dx; a lone splash particle would have ~0.1)", positive=True)
    transport_velocity: bool = opt(False, "Adami, Hu & Adams (2013)'s transport-velocity formulation: particles move with "
                                          "v + dt a_b, a_b the symmetric gradient of a uniform background pressure "
                                          "(`transport_background_pressure`), which pushes them toward a uniform arrangement, "
                                          "and the momentum equation takes the extra stress div(rho v (x) (v_transport - v)) "
                                          "/ rho (physics/momentum.py background_pressure_acceleration, "
                                          "transport_velocity_stress). Needs `wcsph.density: summation` and shifting off; "
                                          "for a fluid that fills its container (the background pressure would pull a free "
                                          "surface apart)")
    transport_background_pressure: float | None = opt(None, "p_b of the transport velocity; None = rho0 c0^2 (Adami et al.'s "
                                                            "p0)", unit="Pa", positive=True)
    wall_clearance: float | None = opt(0.25, "kinematic wall condition (as ISPH's): the speed toward a wall face is cut so "
                                             "that no fluid particle comes closer than this to it (fluid starts dx/2 away). "
                                             "Without it the thin fast layer after a dam-break impact sinks up to 0.32 dx past "
                                             "the floor face (1-3 particles at a time, t = 0.44-0.94 s); None = off",
                                       unit="dx", minimum=0.0)


@dataclass(frozen=True)
class Multigrid:
    smoother_omega: float = opt(0.9, "weighted-Jacobi factor of the V-cycle's smoothing sweeps (every level)", positive=True)
    coarse_scale: float = opt(1.8, "scale s of the coarse-grid correction x += s P y (piecewise-constant aggregates "
                                   "make each Galerkin level ~2x too stiff; any s > 0 keeps CG valid). 2D dam break, "
                                   "100k particles to t = 0.15 s: s 1.6 / 1.8 / 2 / 2.3: 13.9 / 13.8 / 15.9 / 20.7 "
                                   "iterations a step", positive=True)
    cell_sweeps: int = opt(3, "weighted-Jacobi sweeps before and after the coarse correction on each cell level (one on "
                              "the particles); 1 / 2 / 3 sweeps: 22 / 18 / 16 iterations at 650k particles, 14 / 12 / 12 at 43k", minimum=1)
    coarsest_sweeps: int = opt(8, "symmetric Gauss-Seidel sweeps on the coarsest level", minimum=1)


@dataclass(frozen=True)
class PPE:
    solver: str = opt(AUTO, "pressure Poisson solver, matrix-free: CG preconditioned by a multigrid V-cycle on the neighbour "
                            "cells (mgcg), by Jacobi (cg), weighted Jacobi (jacobi), or auto (mgcg from "
                            "isph.ppe.mgcg_from fluid particles, cg below)", choices=("auto", "mgcg", "cg", "jacobi"))
    mgcg_from: int = opt(1000, "fluid-particle count from which solver 'auto' takes mgcg (measured on the 2D dam break: "
                               "mgcg 2.2x faster per step at 1.7k fluid particles, 2.8x at 25k)", minimum=0)
    multigrid: Multigrid = opt(factory=Multigrid, doc="mgcg's V-cycle")

    def solver_for(self, n_fluid: int) -> str:
        """`solver`, with 'auto' resolved by the scene size: mgcg from `mgcg_from` fluid particles, else cg."""
        if self.solver != AUTO:
            return self.solver
        return "mgcg" if n_fluid >= self.mgcg_from else "cg"
    tolerance: float = opt(1e-4, "relative residual ||b - A p|| / ||b|| to stop at", positive=True)
    max_iterations: int = opt(1000, "iteration cap; reaching it is a warning in the summary", minimum=1)
    omega: float = opt(0.6, "weighted-Jacobi relaxation factor", positive=True)
    check_every: int = opt(4, "PPE iterations launched between two host read-backs of the solve state, after the first "
                              "read-back (made after as many iterations as the last solve took); the stopping "
                              "test runs on the device after every iteration (later iterations are empty), so the "
                              "result does not depend on it: it trades read-backs (a device sync each) against "
                              "empty launches after convergence", minimum=1)


@dataclass(frozen=True)
class ISPH:
    source: str = opt("blend", "PPE source: divergence of the intermediate velocity (Cummins & Rudman 1999), density "
                                "invariance (Shao & Lo 2003), or blend", choices=("divergence", "density_invariance", "blend"))
    blend: float | None = opt(None, "weight of the density-invariance source in 'blend'. It is what holds the volume against "
                                   "the drift of the approximate projection and of shifting: on a free surface a volume drift "
                                   "is potential energy (standing wave: 0.1 unstable at 4 s from volume growth, 0.3 +7% energy "
                                   "a period, 1.0 +1.6%; docs/isph.md). In a fluid that fills its container the walls hold "
                                   "the volume and the weight only re-packs the arrangement, turning the summation density's "
                                   "disorder noise into velocity noise (lid-driven cavity, nx 50: per-output centreline RMS "
                                   "0.012-0.065 at 1.0, 0.004-0.018 at 0.1). None = 1.0 with a free surface, 0.1 in a "
                                   "confined fluid (no free-surface particle at the start)", minimum=0.0)
    density: str = opt("summation", "the density the density-invariance source holds at rho0: 'summation' (the kernel sum; "
                                    "at a fixed volume it rises with the arrangement's disorder, ~1.2 sigma^2 at h = 1.3 dx, "
                                    "so the projection expands a disordered fluid) or 'continuity' (each particle's density "
                                    "carried by det(I + grad u) of its step's displacement and of its shift: no disorder "
                                    "bias, no truncated kernel at a free surface, but it fights the shift next to walls. Experimental: tried "
                                    "on the standing wave; the stretching drop gains energy from its first steps with it and "
                                    "ends non-finite; docs/isph.md)", choices=("summation", "continuity"))
    divergence: str = opt("plain", "div(v*) of the divergence source: 'plain' -sum_b V_b v_ab . grad_a W_ab over the lattice's "
                                   "gradient sum, or 'corrected': tr(S_a M_a^-1), S_a = sum_b V_b (v_b - v_a) (x) grad_a W_ab, "
                                   "exact for a linear velocity on any arrangement, as the corrected pressure gradient "
                                   "(physics/ppe_terms.py corrected_velocity_divergence; Bonet & Lok 1999)",
                          choices=("plain", "corrected"))
    ppe: PPE = opt(factory=PPE, doc="PPE solver settings")
    free_surface_threshold: float = opt(0.8, "a particle is free-surface when its kernel sum / lattice kernel sum is below this", positive=True)
    surface_depth: str = opt(AUTO, "depth d of a free-surface particle under the surface in its Dirichlet value "
                                   "p = rho0 |g - a| d: 'fixed' d = dx/2, or 'strained' d carried with the surface's "
                                   "own stretching, d <- d (1 - dt div_t v), div_t v = div v - n . grad v . n (the layer "
                                   "above a particle keeps its area, so it thickens under a crest), dx/2 where a particle "
                                   "joins the surface or has a wall in reach; 'auto' = strained under gravity alone, "
                                   "fixed with a central force or no body force. Standing wave (dx 0.025 / 0.0125): "
                                   "period +0.14% / +0.07% strained against +0.97% / +0.51% fixed; the oscillating drop "
                                   "(central force) 1.57% shape strained against 0.76% fixed (docs/isph.md)",
                             choices=(AUTO, "fixed", "strained"))
    surface_pressure: str = opt(AUTO, "sign of a free-surface particle's Dirichlet value p = rho0 |g - a| d: 'compression' "
                                      "= 0 where grad p = rho0 (g - a) points out of the fluid (no tension at a free "
                                      "surface), 'signed' = -rho0 |g - a| d there, the pressure at the particle's depth "
                                      "in a fluid in tension (a rotating patch: configs/rotating_square_2d.yaml, centre "
                                      "pressure at the start -4.1% -> +2.6%, shape 2.7% -> 0.62%); 'auto' = signed "
                                      "where no body force acts (no gravity, no central force: the surface's pressure "
                                      "gradient is the flow's own acceleration, tension as physical as compression), "
                                      "compression under a body force (dam_break_buchner_2d with signed: 1 of 3 "
                                      "perturbed runs ok; docs/isph.md)", choices=(AUTO, "compression", "signed"))
    one_sided_ratio: float | None = opt(None, "a surface candidate (kernel sum below 0.97 of the lattice's) is also free-surface when "
                                             "its own pressure's push on it, grad C . M^-T grad C, exceeds this fraction of its "
                                             "neighbours' share of the projection's diagonal (a one-sided support: its PPE row "
                                             "cannot hold it; physics/free_surface.py); None = off", positive=True)
    walls: str = opt("neumann", "the wall pressure of the PPE and the correction: 'neumann' (pairwise hydrostatic "
                                "differences p_a - p_w = rho0 g . r_aw in the fluid rows, then Adami's mean in the "
                                "correction: a push the PPE did not see; dam_break_buchner_2d ok in 4 of 6 starts) or "
                                "'extrapolated' (each wall particle with enough fluid in reach is an unknown whose row "
                                "extrapolates its fluid neighbours' pressure hydrostatically, "
                                "sum_f K_wf (p_w - p_f - rho0 g . r_wf) = 0: the system stays symmetric and the correction "
                                "pushes with the p_w the PPE solved for; Buchner ok in 6 of 6 starts, but the 3D wave's "
                                "amplitude 0.899 and a deep wave's period -0.86%, so not the default yet; docs/isph.md)",
                     choices=("neumann", "extrapolated"))
    step_force: str = opt("total", "the acceleration in the step's force limit CFL sqrt(h / |a|): 'total' (predictor and "
                                   "pressure) or 'explicit' (body force and viscous terms: the pressure is the projection's "
                                   "response to the step, ~ 1/dt^2 through the density source, and a limit on it feeds back: "
                                   "a shorter step, a larger correction, a shorter step)", choices=("total", "explicit"))
    max_density_correction: float | None = opt(0.05, "the density error |rho - rho0| / rho0 the density-invariance source "
                                                      "removes in one step at most (physics/ppe_terms.py capped_density_error): "
                                                      "the source removes the whole error a step, so a sudden large error (a "
                                                      "void closing, a run-up merging) would be a pressure pulse of the whole "
                                                      "fluid. A drop into a pool at h = 1.5 dx: 'unstable' at t = 1.25 s in 1 of "
                                                      "3 starts without the cap, ok to 2 s in 3 of 3 with 0.05 (0.02: "
                                                      "'unstable' at 1.73 s in 1 of 2: an impact's compression needs its "
                                                      "correction); drops, waves, hydrostatics, square: identical; "
                                                      "docs/isph.md. null = no cap", minimum=0.0)
    compression_only: bool = opt(False, "density-invariance source corrects compression only (rho floored at rho0): for free-surface "
                                        "flows, where a kernel-sum deficit is not expansion; off in closed boxes (one-sided source drifts)")
    artificial_viscosity_alpha: float | None = opt(None, "Monaghan alpha in ISPH's predictor (on every pair; the floor of the "
                                                         "switch); None = half of wcsph.artificial_viscosity.alpha, which "
                                                         "WCSPH applies to approaching pairs only (dam_break_2d front RMS raw "
                                                         "/ shifted 0.2088 / 0.0480 with the whole alpha, 0.2436 / 0.0419 "
                                                         "with half; docs/isph.md)", minimum=0.0)
    switch_noise: float = opt(2.0, "a second source of the viscosity switch in ISPH (wcsph.artificial_viscosity.switch, on "
                                   "under gravity): alpha_a also rises at this times particle a's noise rate |v_a - v_fit| "
                                   "/ h, v_fit the linear fit of its fluid neighbours' velocities (physics/momentum.py "
                                   "particle_noise_rate). A projected flow's particle noise hardly compresses, so the "
                                   "compression source misses a splash's noise: a drop into a pool at time.cfl 0.125 is "
                                   "'unstable' at 0.57 s with 0, ok with 2; a wave's smooth field reads ~0 "
                                   "(standing_wave_2d unchanged); Buchner's impact ok in 21 of 24 perturbed starts with 2, "
                                   "16 of 18 with 0 (docs/isph.md). 0 = the compression source alone (compiled out)",
                              minimum=0.0)
    cfl: float | None = opt(None, "Courant number of ISPH's adaptive step; None = time.cfl. ISPH's step follows the flow "
                                  "speed, WCSPH's the sound speed, so the same number means steps ~10x apart", positive=True)
    hdx: float | None = opt(None, "h / dx for ISPH; None = particles.hdx, or when that is unset 1.5 in 2D, 1.3 in 1D and 3D (DEFAULT_HDX). ISPH's summation density (its density-invariance "
                                  "source, its density error) spreads with the arrangement's disorder the more the smaller h is: "
                                  "WCSPH's continuity density does not see it", positive=True)
    shifting_coefficient: float | None = opt(None, "A of the particle shift in ISPH; None = shifting.coefficient (ISPH's corrected "
                                                   "pressure gradient has no pairwise repulsion: shifting is all that re-orders its "
                                                   "particles, and it may need a larger A than WCSPH)", minimum=0.0)
    shifting_model: str = opt("shared", "shifting.model for ISPH; 'shared' = shifting.model (ISPH's step is ~10x WCSPH's: "
                                           "with the global speed and A = 4 a shift corrects a particle's offset in about one "
                                           "step, where A = 20 overshoots into the max_shift cap)",
                              choices=("shared", "skillen", "sun"))
    time_integration: str = opt(AUTO, "the step's integrator: 'midpoint' (drift-kick-drift, position Verlet: x "
                                      "moves dt/2 with v^n, the predictor, PPE and correction act at x^{n+1/2}, x "
                                      "moves dt/2 with v^{n+1}; second order), 'euler' (every operator at x^n, "
                                      "x^{n+1} = x^n + dt v^{n+1}; symplectic Euler, first order: at a "
                                      "constant acceleration x runs ahead by g t dt / 2) or 'auto' = midpoint in a "
                                      "fluid that fills its container (Taylor-Green nx 50 and cavity: as euler "
                                      "within run-to-run noise), euler with a free surface (dam_break_buchner_2d's impact compresses more "
                                      "with midpoint: 'unstable' in 1 of 4 starts; docs/isph.md)",
                                choices=(AUTO, "midpoint", "euler"))
    frame: str = opt("lagrangian", "'lagrangian': the particles move with the flow; 'eulerian': they stay where they "
                                   "start and the predictor adds the advection -(v . grad) v with the renormalised "
                                   "velocity gradient (Lind & Stansby 2016; physics/momentum.py eulerian_advection): no "
                                   "disorder and no shift, the summation density stays rho0. Only for a fluid that fills "
                                   "its container (a free surface is refused at the start). Taylor-Green nx 50 / 75 / "
                                   "100: L1 0.0016 / 0.0010 / 0.00065 against 0.0134 / 0.0051 / 0.0023 lagrangian; the "
                                   "lid-driven cavity is worse (centreline RMS at Re 100 0.0061 against 0.0027, at Re 1000 "
                                   "0.057 against 0.0068: explicit central advection, no upwinding; docs/isph.md)",
                     choices=("lagrangian", "eulerian"))
    wall_clearance: float | None = opt(0.25, "kinematic wall condition: the speed toward a wall face is cut so that no fluid particle "
                                             "comes closer than this to it (fluid starts dx/2 away); holds free-surface films, "
                                             "which have no PPE pressure; None = off", unit="dx", minimum=0.0)


@dataclass(frozen=True)
class Time:
    t_end: float = opt(1.0, "simulated end time", unit="s", positive=True)
    dt: float | str = opt(AUTO, "time step: 'auto' (adaptive) or a fixed value", unit="s")
    cfl: float = opt(0.25, "Courant number for the adaptive step", positive=True)
    dt_max: float | None = opt(None, "upper bound of the adaptive step (ISPH flows starting at rest)", unit="s", positive=True)


@dataclass(frozen=True)
class Guards:
    max_density_error: float = opt(0.2, "|rho - rho0| / rho0 beyond which the run is declared unstable", positive=True)
    check_every: int = opt(20, "steps between stability checks", minimum=1)
    energy_growth: float | None = opt(0.1, "growth of the fluid's energy above its rest state (kinetic + potential + "
                                           "WCSPH's elastic), as a fraction of its start, beyond which a run with no "
                                           "energy input (no moving walls, gravity ramp or periodic body force) is "
                                           "declared unstable; checked at output rows; null = off", minimum=0.0)
    particles_outside: float = opt(0.001, "fraction of the fluid particles that may be outside the domain at once before "
                                          "the run is declared unstable (spray over an open tank: such a particle flies "
                                          "on under its body force, with no neighbour, and may fall back in; the run "
                                          "warns with where the first one left); 0 = the first one ends the run",
                                   minimum=0.0)


@dataclass(frozen=True)
class Output:
    every: float = opt(0.02, "simulated time between output rows (timeseries, probes, metrics)", unit="s", positive=True)
    snapshot_every: float | None = opt(None, "simulated time between NPZ/VTU snapshots; None = at the end only", unit="s", positive=True)
    checkpoint_every: float | str | None = opt(AUTO, "simulated time between checkpoints (full solver state, written "
                                                     "atomically; `taichi-sph resume` continues from the last one); "
                                                     "'auto' = t_end / 10 (a killed run loses at most a tenth); None = "
                                                     "only at the end or on Ctrl-C", unit="s")


@dataclass(frozen=True)
class Render:
    enabled: bool = opt(True, "write frames and a video (also off with --no-render)")
    every: float = opt(0.02, "simulated time between frames", unit="s", positive=True)
    width: int = opt(960, "frame width", unit="px", minimum=16)
    height: int = opt(540, "frame height", unit="px", minimum=16)
    colour_by: str = opt("speed", "field the particles are coloured by", choices=("speed", "pressure", "density_error", "kind"))
    range: tuple[float, ...] | None = opt(None, "fixed colour range [lo, hi]; None = automatic")
    show_walls: bool = opt(True, "draw wall particles (faint grey)")
    camera_position: tuple[float, ...] | None = opt(None, "3D camera position; None = framing the domain", unit="m")
    camera_lookat: tuple[float, ...] | None = opt(None, "3D camera target; None = domain centre", unit="m")
    video: str = opt("mp4", "video assembled from the frames", choices=("mp4", "gif", "none"))
    fps: int = opt(30, "video frame rate", minimum=1)
    particle_scale: float = opt(1.0, "drawn radius = 0.5 dx x this", positive=True)


@dataclass(frozen=True)
class Realtime:
    min_particles_across: float = opt(8.0, "--realtime never runs coarser than this many particles across the narrowest "
                                           "fluid body (its smallest extent, or a sphere's diameter): the coarsest dx at "
                                           "which the scene still means something", positive=True)
    margin: float = opt(1.25, "--realtime picks the finest dx whose predicted real-time factor (simulated s per wall s) "
                              "is at least this", positive=True)


@dataclass(frozen=True)
class Probe:
    name: str = opt("probe", "column name in timeseries.csv")
    quantity: str = opt("pressure", "what the probe measures (kernel-weighted over fluid); elevation: the free-surface height "
                                    "above the position's horizontal coordinates (its vertical one is ignored)",
                        choices=("pressure", "velocity_x", "density", "elevation"))
    position: tuple[float, ...] = opt((0.0, 0.0), "probe location", unit="m")


@dataclass(frozen=True)
class Metric:
    type: str = opt("hydrostatic", "reference metric written to summary.json errors",
                    choices=("hydrostatic", "surge_front", "taylor_green", "poiseuille", "cavity", "column_fall",
                             "probe_pressure", "drop_ellipse", "rotating_square", "standing_wave"))
    depth: float | None = opt(None, "hydrostatic / standing_wave: fluid depth H", unit="m", positive=True)
    amplitude: float | None = opt(None, "standing_wave: the wave's amplitude a", unit="m", positive=True)
    floor: float = opt(0.0, "hydrostatic / surge_front: floor height", unit="m")
    column_width: float | None = opt(None, "surge_front: column width a", unit="m", positive=True)
    origin: float = opt(0.0, "surge_front: x of the wall the column leans on; standing_wave: x of the tank's left wall", unit="m")
    t_max: float = opt(3.0, "surge_front: last dimensionless time T compared")
    lid_velocity: float = opt(1.0, "cavity: lid speed", unit="m/s")
    strain_rate: float = opt(0.0, "drop_ellipse: A0 of the first fluid_sphere's initial velocity A0 (x - c, c - y) about its "
                                  "centre c", unit="1/s")
    angular_velocity: float = opt(1.0, "rotating_square: omega of the first fluid_block's initial rigid rotation u = omega "
                                       "(y - y_c, x_c - x) about its centre (clockwise for omega > 0)", unit="1/s")
    width: float = opt(1.0, "poiseuille / cavity: channel or cavity width; standing_wave: tank length", unit="m")
    probe: str = opt("", "probe_pressure: name of the probe (see probes) compared with the reference")
    reference: str = opt("dambreak_buchner2002_pressure_probe_pysph",
                         "probe_pressure: bundled reference table with columns t_star = t sqrt(g/H), p_star = p/(rho0 g H)")


@dataclass(frozen=True)
class Config:
    name: str = opt("", "scene name (default: the file's stem)")
    description: str = opt("", "one line shown by `taichi-sph list`")
    dim: int = opt(2, "spatial dimension", choices=(1, 2, 3))
    solver: str = opt("wcsph", "time-stepping scheme", choices=("wcsph", "isph"))
    precision: str = opt("f32", "floating-point precision of all fields", choices=("f32", "f64"))
    float64: bool | str = opt(AUTO, "64-bit floats for the simulated clock (t, dt) and the PPE's stopping test "
                                    "|r| / |b|: auto = where the device has them (not Apple GPUs through MoltenVK); "
                                    "false = f32 only (a clock rebased every call, an f32 stopping test); true = "
                                    "required")
    arch: str = opt("cpu", "Taichi backend", choices=("cpu", "cuda", "vulkan", "gpu", "auto"))
    seed: int = opt(0, "random seed (initial jitter, random velocity expressions)")
    gravity: tuple[float, ...] | None = opt(None, "body acceleration (dim numbers); None or zeros compiles it out", unit="m/s^2")
    gravity_ramp: float = opt(0.0, "time over which gravity rises smoothly from 0 to its value, "
                                   "g (1 - cos(pi t / t_ramp)) / 2 (Adami et al. 2012 damping); 0 = off", unit="s", minimum=0.0)
    central_force: CentralForce = opt(factory=CentralForce, doc="harmonic body force toward a point")
    domain: Domain = opt(factory=Domain, doc="simulation box")
    particles: Particles = opt(factory=Particles, doc="discretisation")
    fluid: Fluid = opt(factory=Fluid, doc="material")
    bodies: tuple[Body, ...] = opt((), "fluid and wall bodies (list)")
    reflecting: Reflecting = opt(factory=Reflecting, doc="reflecting domain faces")
    walls: Walls = opt(factory=Walls, doc="wall boundary condition")
    wcsph: WCSPH = opt(factory=WCSPH, doc="WCSPH options")
    isph: ISPH = opt(factory=ISPH, doc="ISPH options")
    shifting: Shifting = opt(factory=Shifting, doc="particle shifting")
    time: Time = opt(factory=Time, doc="time stepping")
    guards: Guards = opt(factory=Guards, doc="stability guards")
    output: Output = opt(factory=Output, doc="output cadence")
    render: Render = opt(factory=Render, doc="offscreen rendering")
    realtime: Realtime = opt(factory=Realtime, doc="--realtime: the resolution chosen for this machine")
    probes: tuple[Probe, ...] = opt((), "point probes (list)")
    metrics: tuple[Metric, ...] = opt((), "reference metrics (list)")

    # -- derived quantities ------------------------------------------------------------
    @property
    def h(self) -> float:
        """Smoothing length h = hdx * dx."""
        return self.hdx * self.particles.dx

    @property
    def support_layers(self) -> int:
        """Particle layers this run's kernel support spans: ceil(support radius / dx)."""
        return int(math.ceil(KERNEL_SUPPORT[self.particles.kernel] * self.h / self.particles.dx - 1e-9))

    def wall_layers(self, body: Body) -> int:
        """A wall_box's particle layers: its `layers`, or (None) `support_layers`, so that a fluid particle at the
        wall has a full support."""
        return body.layers if body.layers is not None else self.support_layers

    def wall_box_extent(self, body: Body) -> tuple[list[float], list[float]]:
        """The outer corners of a wall_box's particle layers (its lo/hi grown by the layers; not above an open top)."""
        d, thick = self.dim, self.wall_layers(body) * self.particles.dx
        lo = [body.lo[a] - thick for a in range(d)]
        hi = [body.hi[a] + (0.0 if (body.open_top and a == d - 1) else thick) for a in range(d)]
        return lo, hi

    def _isph_override(self, name: str) -> bool:
        """Whether this run takes `isph.<name>` (an ISPH run with it set) rather than the shared key."""
        return self.solver == "isph" and getattr(self.isph, name) is not None

    def for_solver(self, name: str, shared):
        """`isph.<name>` in an ISPH run when it is set, else the `shared` value."""
        return getattr(self.isph, name) if self._isph_override(name) else shared

    def solver_key(self, name: str, shared_key: str) -> str:
        """The key `for_solver(name, ...)` reads for this run, for messages: 'isph.<name>' or `shared_key`."""
        return f"isph.{name}" if self._isph_override(name) else shared_key

    @property
    def cfl(self) -> float:
        """Courant number of the adaptive step for this run's solver (isph.cfl or time.cfl)."""
        return self.for_solver("cfl", self.time.cfl)

    @property
    def hdx(self) -> float:
        """h / dx for this run's solver (isph.hdx, particles.hdx, or the solver's DEFAULT_HDX)."""
        hexagonal = self.particles.packing == "hexagonal" and self.solver == "wcsph" and self.particles.kernel == "wendland_c2"
        default = HEXAGONAL_HDX if hexagonal else DEFAULT_HDX[self.solver][self.dim]
        shared = self.particles.hdx if self.particles.hdx is not None else default
        return self.for_solver("hdx", shared)

    @property
    def central_force_center(self) -> tuple[float, ...]:
        """The point of the central force: `central_force.center`, or the domain centre."""
        c = self.central_force.center
        if c is None:
            return tuple(0.5 * (lo + hi) for lo, hi in zip(self.domain.lo, self.domain.hi))
        return c

    @property
    def periodic(self) -> tuple[bool, ...]:
        return self.domain.periodic if self.domain.periodic is not None else (False,) * self.dim

    @property
    def gravity_vector(self) -> tuple[float, ...]:
        return self.gravity if self.gravity is not None else (0.0,) * self.dim

    @property
    def moving_walls(self) -> bool:
        """A wall body with a nonzero (or expression) velocity, or a prescribed motion."""
        return self.sliding_walls or bool(self.wall_motions)

    @property
    def sliding_walls(self) -> bool:
        """A wall body with a nonzero (or expression) velocity: its surface slides along its faces (a lid)."""
        return any(b.type.startswith("wall") and b.velocity is not None and any(c != 0 for c in b.velocity)
                   for b in self.bodies)

    @property
    def wall_motions(self) -> tuple[tuple[int, "Motion"], ...]:
        """(index in bodies, motion) of each wall body with a prescribed oscillation, in body order."""
        return tuple((i, b.motion) for i, b in enumerate(self.bodies) if b.type.startswith("wall") and b.motion)

    @property
    def wall_motion_speed(self) -> float:
        """The largest speed a prescribed wall motion reaches, max |A| 2 pi / T (the ramp's overshoot aside)."""
        return max((math.sqrt(sum(a * a for a in m.amplitude)) * 2.0 * math.pi / m.period
                    for _, m in self.wall_motions), default=0.0)

    @property
    def wall_refinement(self) -> int:
        """Wall particles per fluid spacing along each axis: `walls.refinement`, or (auto) 2 for WCSPH on a
        hexagonal packing, 1 otherwise."""
        if self.walls.refinement != AUTO:
            return int(self.walls.refinement)
        return 2 if self.particles.packing == "hexagonal" and self.solver == "wcsph" else 1

    @property
    def wall_dx(self) -> float:
        """The wall particles' spacing, dx / wall_refinement."""
        return self.particles.dx / self.wall_refinement

    @property
    def has_gravity(self) -> bool:
        return any(g != 0.0 for g in self.gravity_vector)

    @property
    def sound_speed(self) -> float:
        """c0: the given value, or c0_factor x the larger of the reference speed and the body force's speed scale
        (body_force_speed): Morris, Fox & Zhu (1997), c0^2 >= max(U^2, |g| L) / delta with delta = 1 / c0_factor^2."""
        if self.fluid.c0 != AUTO:
            return float(self.fluid.c0)
        return self.fluid.c0_factor * max(self.expected_speed, self.body_force_speed)

    @property
    def sound_speed_source(self) -> str:
        """Where `sound_speed` came from, for messages: the key, or the speed scale c0_factor multiplied."""
        if self.fluid.c0 != AUTO:
            return "fluid.c0"
        factor = f"{self.fluid.c0_factor:g} x"
        if self.body_force_speed > self.expected_speed:
            return f"{factor} sqrt(|g| L) {self.body_force_speed:.3g} m/s, the body force over the fluid"
        if self.fluid.reference_speed is not None:
            return f"{factor} fluid.reference_speed {self.fluid.reference_speed:g} m/s"
        return f"{factor} sqrt(2 g H) over the domain's height, {self.expected_speed:.3g} m/s"

    @property
    def body_force_speed(self) -> float:
        """sqrt(|g| L), L the fluid bodies' extent along g: the body force's pressure over the fluid, rho |g| L, is
        rho c0^2 / c0_factor^2 at c0 = c0_factor x this. Under gravity onto a floor it is sqrt(|g| H) and the
        reference speed sqrt(2 |g| H) exceeds it; in a channel driven along a periodic axis the reference speed is
        the flow's, far below it: a user's channel past a square obstacle (U 0.05 m/s, g 0.25 m/s^2, L 0.1 m)
        at c0 0.5 m/s ran with a 15% density error and a flux 16% high; at c0 1.6 (this) 4.6% and the flux of c0 5."""
        g = math.sqrt(sum(x * x for x in self.gravity_vector))
        if g == 0.0:
            return 0.0
        unit = [x / g for x in self.gravity_vector]
        along: list[float] = []
        for b in self.bodies:
            if b.type == "fluid_block" and b.lo is not None and b.hi is not None:
                along += [sum(u * (hi if u > 0 else lo) for u, lo, hi in zip(unit, b.lo, b.hi)),
                          sum(u * (lo if u > 0 else hi) for u, lo, hi in zip(unit, b.lo, b.hi))]
            elif b.type == "fluid_sphere" and b.center is not None and b.radius is not None:
                c = sum(u * x for u, x in zip(unit, b.center))
                along += [c - b.radius, c + b.radius]
        return math.sqrt(g * (max(along) - min(along))) if along else 0.0

    @property
    def expected_speed(self) -> float:
        """The scene's declared reference speed, else the larger of sqrt(2 |g| H_domain) (else 1 m/s) and the
        fastest prescribed wall motion's speed."""
        if self.fluid.reference_speed is not None:
            return self.fluid.reference_speed
        g = math.sqrt(sum(x * x for x in self.gravity_vector))
        speed = 1.0
        if g > 0:
            height = self.domain.hi[-1] - self.domain.lo[-1]
            speed = math.sqrt(2.0 * g * height)
        return max(speed, self.wall_motion_speed)

    @property
    def skin_fraction(self) -> float:
        """Verlet skin / support radius ('auto': 0.15 for WCSPH, 0 for ISPH whose steps move particles ~h/4)."""
        if self.particles.skin == AUTO:
            return 0.15 if self.solver == "wcsph" else 0.0
        return float(self.particles.skin)

    @property
    def viscosity_switch(self) -> bool:
        """Morris & Monaghan's switch, where its ceiling lies above this run's alpha (the floor it decays to)."""
        av = self.wcsph.artificial_viscosity
        if av.alpha_max <= self.artificial_viscosity[0]:
            return False
        if av.switch == AUTO:
            along_periodic = any(g != 0.0 and self.periodic[a] for a, g in enumerate(self.gravity_vector))
            return self.has_gravity and not along_periodic
        return av.switch == "morris_monaghan"

    @property
    def artificial_viscosity(self) -> tuple[float, float]:
        """(alpha, beta) of the Monaghan viscosity for this run's solver."""
        av = self.wcsph.artificial_viscosity
        shared = ISPH_SHARED_ALPHA_FACTOR * av.alpha if self.solver == "isph" else av.alpha
        return self.for_solver("artificial_viscosity_alpha", shared), av.beta

    @property
    def shifting_model(self) -> str:
        """The particle shift's speed model for this run's solver (isph.shifting_model or shifting.model)."""
        own = self.isph.shifting_model
        return own if self.solver == "isph" and own != "shared" else self.shifting.model

    @property
    def shifting_coefficient(self) -> float:
        """A of the particle shift for this run's solver (isph.shifting_coefficient or shifting.coefficient)."""
        shared = SHIFTING_COEFFICIENT if self.shifting.coefficient is None else self.shifting.coefficient
        return self.for_solver("shifting_coefficient", shared)

    @property
    def checkpoint_interval(self) -> float | None:
        """Simulated time between checkpoints: `output.checkpoint_every`, 'auto' = t_end / 10, None = off."""
        every = self.output.checkpoint_every
        if every == AUTO:
            return self.time.t_end / 10.0
        return None if every is None else float(every)

    @property
    def shifting_enabled(self) -> bool:
        if self.shifting.enabled is None:
            return self.solver == "isph"
        return self.shifting.enabled

    @property
    def isph_surface_pressure(self) -> str:
        """`isph.surface_pressure` resolved: 'auto' is signed with no body force, compression under one."""
        if self.isph.surface_pressure != AUTO:
            return self.isph.surface_pressure
        return "compression" if self.has_gravity or self.central_force.omega > 0 else "signed"

    @property
    def isph_surface_depth(self) -> str:
        """`isph.surface_depth` resolved: 'auto' is strained under gravity alone, fixed otherwise."""
        if self.isph.surface_depth != AUTO:
            return self.isph.surface_depth
        return "strained" if self.has_gravity and self.central_force.omega == 0 else "fixed"

    @property
    def wall_clearance(self) -> float | None:
        """The running solver's kinematic wall clearance in dx (`wcsph.` or `isph.wall_clearance`; None: off)."""
        return self.isph.wall_clearance if self.solver == "isph" else self.wcsph.wall_clearance

    @property
    def shifting_walls(self) -> str:
        """`shifting.walls` resolved: 'auto' is the mirror for ISPH with its kinematic wall faces, else the particles."""
        if self.shifting.walls != AUTO:
            return self.shifting.walls
        return "mirror" if self.solver == "isph" and self.wall_clearance is not None else "particles"


# ----------------------------------------------------------------------------- generic loader


# ----------------------------------------------------------------------------- YAML, extends, overrides


# ----------------------------------------------------------------------------- cross-field validation


# ----------------------------------------------------------------------------- resolved form and docs


