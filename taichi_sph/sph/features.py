"""The frozen feature set a scene needs: it decides what is compiled into the solver kernels
(through `ti.static`) and which fields are allocated."""

from __future__ import annotations

from dataclasses import asdict, dataclass

from taichi_sph.config.schema import Config


@dataclass(frozen=True)
class Features:
    """Everything that changes the compiled code. Derived from the config, never set by hand."""

    dim: int
    solver: str
    kernel: str
    precision: str
    wide: str                     # the clock's and the PPE stopping test's float: f64, or f32 without 64-bit floats
    walls: bool
    moving_walls: bool
    wall_motion: bool             # a wall body with a prescribed oscillation (solvers/wall_motion.py)
    no_slip: bool
    ghost_velocity: bool          # Adami's no-slip wall velocity: the laminar viscosity's at a no-slip wall
    free_slip_normal_viscosity: bool  # the artificial viscosity's wall pairs along the face normal only
    gravity: bool
    central_force: bool
    laminar_viscosity: bool
    laplacian: str                # morris | normalised | renormalised | consistent (the laminar viscosity's)
    artificial_viscosity: bool
    viscosity_switch: bool        # Morris & Monaghan's per-particle alpha
    switch_noise_source: bool     # ISPH: the switch's second source, the particle noise rate (isph.switch_noise)
    density: str                  # continuity | summation (WCSPH); ISPH always uses summation for its source
    density_diffusion: str        # none | molteni | fourtakas | antuono
    tensile_correction: bool
    tensile_instability_control: bool  # Sun et al. 2017's difference form in tension (WCSPH)
    surface_scaled_pressure: bool      # p / (S / S_lattice) in the symmetric pressure gradient (WCSPH)
    pressure_gradient: str        # symmetric | corrected | corrected_symmetric (WCSPH; ISPH's is always corrected)
    gradient_normalisation: str   # lattice | none: WCSPH's symmetric gradient and plain continuity divergence / kappa
    integrator: str
    periodic: tuple[bool, ...]
    reflecting: bool
    shifting: bool
    shifting_model: str           # skillen | sun (solvers/shifting.py)
    shifting_correction: bool     # Taylor correction of v after the shift
    shifting_density: str         # continuity | taylor | fixed: WCSPH's continuity density after a shift; none otherwise
    clamp_negative_pressure: bool
    transport_velocity: bool      # Adami et al. 2013's transport velocity and its extra stress (WCSPH)

    @classmethod
    def from_config(cls, cfg: Config, n_wall: int, wide: str = "f64") -> "Features":
        wc = cfg.wcsph
        walls = n_wall > 0
        moving = cfg.moving_walls
        diffusion = wc.density_diffusion.model
        if wc.density_diffusion.delta == 0.0 or cfg.solver != "wcsph" or wc.density != "continuity":
            diffusion = "none"
        if diffusion == "fourtakas" and not cfg.has_gravity:
            diffusion = "molteni"  # no hydrostatic part to remove
        alpha, beta = cfg.artificial_viscosity
        artificial = alpha > 0.0 or beta > 0.0 or cfg.viscosity_switch
        return cls(
            dim=cfg.dim,
            solver=cfg.solver,
            kernel=cfg.particles.kernel,
            precision=cfg.precision,
            wide=wide,
            walls=walls,
            moving_walls=walls and moving,
            wall_motion=walls and bool(cfg.wall_motions),
            no_slip=walls and cfg.walls.slip == "no_slip",
            ghost_velocity=walls and cfg.walls.slip == "no_slip" and cfg.fluid.nu > 0.0,
            free_slip_normal_viscosity=(artificial and walls and cfg.walls.slip == "free_slip"
                                        and cfg.walls.artificial_viscosity == "normal"),
            gravity=cfg.has_gravity,
            central_force=cfg.central_force.omega > 0.0,
            laminar_viscosity=cfg.fluid.nu > 0.0,
            # ISPH takes 'normalised' for WCSPH's per-particle forms (solvers/base.py)
            laplacian=("normalised" if cfg.solver == "isph" and cfg.fluid.laplacian in ("renormalised", "consistent")
                       else cfg.fluid.laplacian),
            artificial_viscosity=artificial,
            viscosity_switch=cfg.viscosity_switch,
            switch_noise_source=cfg.viscosity_switch and cfg.solver == "isph" and cfg.isph.switch_noise > 0.0,
            density=wc.density if cfg.solver == "wcsph" else "summation",
            density_diffusion=diffusion,
            tensile_correction=cfg.solver == "wcsph" and wc.tensile_correction.enabled,
            tensile_instability_control=cfg.solver == "wcsph" and wc.tensile_instability_control,
            surface_scaled_pressure=cfg.solver == "wcsph" and wc.surface_pressure_gradient == "kernel_sum_scaled",
            pressure_gradient=wc.pressure_gradient if cfg.solver == "wcsph" else "corrected",
            gradient_normalisation=wc.gradient_normalisation if cfg.solver == "wcsph" else "none",
            integrator=wc.integrator if cfg.solver == "wcsph" else "symplectic_euler",
            periodic=tuple(cfg.periodic),
            reflecting=cfg.reflecting.enabled,
            shifting=cfg.shifting_enabled,
            shifting_model=cfg.shifting_model,
            shifting_correction=cfg.shifting_enabled and cfg.shifting.velocity_correction,
            shifting_density=(cfg.shifting.density if cfg.shifting_enabled and cfg.solver == "wcsph"
                              and wc.density == "continuity" else "none"),
            clamp_negative_pressure=cfg.solver == "wcsph" and wc.clamp_negative_pressure,
            transport_velocity=cfg.solver == "wcsph" and wc.transport_velocity,
        )

    def compiled_in(self) -> list[str]:
        """Human-readable list of the terms compiled into this run's kernels."""
        terms = [f"{self.solver}", f"kernel:{self.kernel}", f"dim:{self.dim}", f"precision:{self.precision}"]
        if self.wide != "f64":
            terms.append(f"clock_and_stopping_test:{self.wide}")
        if self.solver == "wcsph":
            terms += ["tait_eos", f"{self.pressure_gradient}_pressure_gradient", f"density:{self.density}", f"integrator:{self.integrator}"]
            if self.gradient_normalisation == "lattice":
                terms.append("lattice_normalised_gradient")
            if self.density_diffusion != "none":
                terms.append(f"density_diffusion:{self.density_diffusion}")
            if self.tensile_correction:
                terms.append("monaghan_tensile_correction")
            if self.tensile_instability_control:
                terms.append("tensile_instability_control")
            if self.surface_scaled_pressure:
                terms.append("kernel_sum_scaled_pressure")
            if self.transport_velocity:
                terms.append("transport_velocity")
        if self.artificial_viscosity:
            terms.append("monaghan_artificial_viscosity" + (":morris_monaghan_switch" if self.viscosity_switch else "")
                         + (":noise_source" if self.switch_noise_source else ""))
        if self.laminar_viscosity:
            terms.append("morris_laminar_viscosity" + ("" if self.laplacian == "morris" else f":{self.laplacian}"))
        if self.gravity:
            terms.append("body_force")
        if self.central_force:
            terms.append("central_force")
        if self.walls:
            terms.append("adami_walls:" + ("no_slip" if self.no_slip else "free_slip")
                         + (":normal_artificial_viscosity" if self.free_slip_normal_viscosity else ""))
        if self.wall_motion:
            terms.append("oscillating_walls")
        if any(self.periodic):
            terms.append("periodic:" + "".join("xyz"[a] for a, p in enumerate(self.periodic) if p))
        if self.reflecting:
            terms.append("reflecting_faces")
        if self.shifting:
            terms.append(f"particle_shifting:{self.shifting_model}")
            if self.shifting_correction:
                terms.append("shifting_taylor_correction")
            if self.shifting_density != "none":
                terms.append(f"shifting_density:{self.shifting_density}")
        if self.clamp_negative_pressure:
            terms.append("clamp_negative_pressure")
        return terms

    def as_dict(self) -> dict:
        return asdict(self)
