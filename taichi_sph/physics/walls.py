"""Wall boundary: Adami, Hu & Adams (2012) pressure and velocity extrapolation to wall particles, and the
kinematic no-penetration condition for particles the pressure cannot hold off a wall.

The kinematic condition acts on the faces of the wall bodies (scene/bodies.py `wall_face_planes`): a wall's
`velocity` is its surface sliding along its faces (a lid), not the face moving, and only a body with a prescribed
`motion` (oscillating_wall: a piston, a shaken tank) carries its particles and faces with it. The condition is
v . n >= v_w . n - (d - c) / dt (d the distance to the face, c the clearance, v_w . n = 0 but for a moving face). A box claims only its own particles, and no face is perpendicular to a periodic axis. Why
the condition once acted along the cavity's lid, and what it measured: docs/notes/walls.md.
"""

import math

import taichi as ti

# a fluid particle nearer a wall face than this many dx is pressed inside its rest distance: the lattice puts the
# first fluid layer dx/2 off each face; the margin keeps an undisturbed layer out (docs/isph.md, session 34)
PRESSED_DISTANCE = 0.45


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
def oscillating_wall(amplitude, omega: float, ramp: float, t: float):
    """A prescribed wall oscillation and its first two time derivatives: d(t) = r(t) A sin(omega t), with the ramp
    r = (1 - cos(pi t / t_r)) / 2 for t < t_r (1 after, and for t_r = 0), so that a wall starts from rest without a
    jerk in its velocity. Returns (d, d', d'')."""
    s, c = ti.sin(omega * t), ti.cos(omega * t)
    r, dr, ddr = 1.0, 0.0, 0.0
    if t < ramp:
        k = math.pi / ramp
        r = 0.5 * (1.0 - ti.cos(k * t))
        dr = 0.5 * k * ti.sin(k * t)
        ddr = 0.5 * k * k * ti.cos(k * t)
    d = r * s * amplitude
    v = (dr * s + r * omega * c) * amplitude
    a = (ddr * s + 2.0 * dr * omega * c - r * omega * omega * s) * amplitude
    return d, v, a


@ti.func
def kinematic_wall_condition(v, normal, distance: float, clearance: float, dt: float, wall_speed: float = 0.0):
    """No flow through a wall face (v . n = v_w . n), as a limit on the approach speed: the particle at
    `distance` from the face (unit `normal` into the fluid) may approach it by at most
    distance - clearance in this step: v . n >= v_w . n - max(distance - clearance, 0) / dt, where
    `wall_speed` = v_w . n is the face's own speed along its normal (0 but for a prescribed motion; a lid slides
    along its faces). Tangential velocity is untouched and a particle is never pushed away. Returns (v, 1 if it
    cut)."""
    out = v
    cut = 0
    floor = wall_speed - ti.max(distance - clearance, 0.0) / dt
    vn = v.dot(normal)
    if vn < floor:
        out = v + (floor - vn) * normal
        cut = 1
    return out, cut


@ti.func
def free_slip_relative_velocity(v_aw, normal):
    """The relative velocity a free-slip wall w shows fluid particle a in a viscous pair term: its part along w's
    face normal, (v_aw . n) n. A free-slip wall exerts no tangential stress; the whole v_a - v_w in Monaghan's
    artificial viscosity, mu ~ h v_aw . r_aw / r^2, is a friction on a particle sliding along a resting wall
    (every wall neighbour off its normal has v_aw . r_aw != 0), while the normal part still resists approach."""
    return v_aw.dot(normal) * normal


@ti.func
def pressed_wall_pressure(p_wall: float, p_a: float, hydrostatic_difference: float) -> float:
    """The pressure of wall w, along w's face normal, in the pressure gradient of an ISPH unknown a pressed inside its
    rest distance (nearer w's face than PRESSED_DISTANCE; along the wall Adami's value stands, solvers/isph.py
    pressure_gradient_pair): max(p_w, p_a - rho0 (g - a_w) . r_aw), Adami's mean but never below the
    Neumann value a's own PPE row assumed (p_a - p_w = rho0 (g - a_w) . r_aw). Adami's mean is a weighted mean of
    the fluid near w; for a particle pressed into a wall with a pressure above its neighbours' it lies below p_a,
    and the difference form (p_w - p_a) grad W then pulls the particle on into the wall, which its row did not
    plan: its kernel sum rises, the next source raises p_a again (the tip of a run-up film on dam_break_buchner_2d's
    wall: 48 -> 273 kPa in six steps, then up the wall at 20 m/s)."""
    return ti.max(p_wall, p_a - hydrostatic_difference)
