"""Wall boundary: Adami, Hu & Adams (2012) pressure and velocity extrapolation to wall particles, and the
kinematic no-penetration condition for particles the pressure cannot hold off a wall."""

import taichi as ti


@ti.func
def adami_wall_pressure(sum_pw: float, sum_rho_rw, sum_w: float, body_acc) -> float:
    """p_w = (sum_f p_f W_wf + (g - a_w) . sum_f rho_f r_wf W_wf) / sum_f W_wf, r_wf = x_w - x_f."""
    p = 0.0
    if sum_w > 0.0:
        p = (sum_pw + body_acc.dot(sum_rho_rw)) / sum_w
    return p


@ti.func
def adami_wall_velocity(v_wall, sum_vw, sum_w: float):
    """No-slip ghost velocity: v_hat_w = 2 v_w - sum_f v_f W_wf / sum_f W_wf."""
    v = v_wall
    if sum_w > 0.0:
        v = 2.0 * v_wall - sum_vw / sum_w
    return v


@ti.func
def kinematic_wall_condition(v, v_wall, normal, distance: float, clearance: float, dt: float):
    """No flow through a wall face (v_n = v_wall,n), as a limit on the approach speed: the particle at
    `distance` from the face (unit `normal` into the fluid) may approach it, relative to the wall, by at
    most distance - clearance in this step: (v - v_wall) . n >= -max(distance - clearance, 0) / dt.
    Tangential velocity is untouched and a particle is never pushed away. Returns (v, 1 if it cut)."""
    out = v
    cut = 0
    floor = -ti.max(distance - clearance, 0.0) / dt
    vn = (v - v_wall).dot(normal)
    if vn < floor:
        out = v + (floor - vn) * normal
        cut = 1
    return out, cut
