"""The square lattice's shear stiffness under pressure (scene/lattice.py lattice_shear_stiffness): the lattice sum
behind WCSPH's standing-wave period bias (docs/wcsph.md). numpy only."""

import pytest

from taichi_sph.scene.lattice import lattice_shear_stiffness
from taichi_sph.sph.kernels import make_kernel


def stiffness(name: str, dim: int, hdx: float) -> tuple[float, float]:
    k = make_kernel(name, dim, hdx)  # dx = 1
    return lattice_shear_stiffness(k.w_np, dim, 1.0, k.support_radius)


def test_wendland_c2_at_two_dx_resists_both_shears():
    """WCSPH's default (Wendland C2, h = 2 dx): the kernel sum grows under either shear (a restoring elastic
    stress times p), axis 0.0377, diagonal 0.0147 in 2D; the standing wave's period is -0.95% there."""
    axis, diagonal = stiffness("wendland_c2", 2, 2.0)
    assert axis == pytest.approx(0.0377, abs=1e-3)
    assert diagonal == pytest.approx(0.0147, abs=1e-3)


def test_the_stiffness_swings_in_sign_with_h():
    """Between h = 2.0 and 2.1 dx the mean of the two changes sign, as the measured period does (-0.95% to
    +0.57%; +0.07% at 2.06 dx, where the mean is within 0.003 of zero)."""
    assert sum(stiffness("wendland_c2", 2, 2.0)) > 0.04
    assert sum(stiffness("wendland_c2", 2, 2.1)) < -0.02
    assert abs(sum(stiffness("wendland_c2", 2, 2.06)) / 2) < 0.003


@pytest.mark.parametrize("dim", [2, 3])
def test_a_wider_kernel_is_closer_to_the_continuum(dim: int):
    """A continuum kernel sum does not change under an area-preserving shear: the lattice's curvature falls as the
    kernel spans more spacings (Wendland C2, h = 4 dx against 2 dx: 9x smaller along the axes in 2D, 16x in 3D)."""
    narrow, wide = stiffness("wendland_c2", dim, 2.0), stiffness("wendland_c2", dim, 4.0)
    assert abs(wide[0]) < 0.15 * abs(narrow[0])
    assert max(abs(v) for v in wide) < 0.005
