"""NeighborSearch against brute force: open and periodic boxes in 1D/2D/3D, reordering, guards."""

import numpy as np
import pytest
import taichi as ti

from taichi_sph.errors import ConfigError
from taichi_sph.sph.neighbors import NeighborSearch

TOL = 1e-5  # pairs within TOL * support of the cut-off may go either way (float32 positions)


def as_fp(values) -> np.ndarray:
    """values in the numpy dtype of Taichi's default float (f32 in the tests, f64 if re-initialised)."""
    f64 = ti.lang.impl.get_runtime().default_fp == ti.f64
    return np.asarray(values, dtype=np.float64 if f64 else np.float32)


def vec_field(values: np.ndarray):
    f = ti.Vector.field(values.shape[1], float, values.shape[0])
    f.from_numpy(as_fp(values))
    return f


def min_image(d: np.ndarray, lo, hi, periodic) -> np.ndarray:
    """Pairwise differences d[..., axis] folded to the minimum image on periodic axes."""
    d = d.copy()
    for a, p in enumerate(periodic):
        if p:
            length = hi[a] - lo[a]
            d[..., a] -= length * np.round(d[..., a] / length)
    return d


def check_against_brute_force(ns: NeighborSearch, x_np: np.ndarray, lo, hi, periodic) -> None:
    """Every list holds distinct true neighbours (never i) and every clear neighbour is listed."""
    x64 = x_np.astype(np.float64)
    dist = np.linalg.norm(min_image(x64[:, None, :] - x64[None, :, :], lo, hi, periodic), axis=-1)
    np.fill_diagonal(dist, np.inf)
    s = ns.support_radius
    count = ns.count.to_numpy()
    nb = ns.neighbors.to_numpy()
    assert not ns.overflowed()
    for i in range(len(x64)):
        found = nb[i, : count[i]]
        assert len(set(found.tolist())) == count[i], f"duplicate neighbour of {i}"
        assert i not in found
        required = set(np.nonzero(dist[i] < s * (1 - TOL))[0].tolist())
        allowed = set(np.nonzero(dist[i] < s * (1 + TOL))[0].tolist())
        assert required <= set(found.tolist()) <= allowed, f"particle {i}"
    assert ns.max_count() == count.max()


# ---------------------------------------------------------------- open boxes

OPEN_CASES = {  # dim: (n, support) with ~25-35 neighbours on average
    1: (300, 0.05),
    2: (700, 0.11),
    3: (900, 0.21),
}


@pytest.mark.parametrize("dim", [1, 2, 3])
def test_open_box_matches_brute_force(dim):
    n, support = OPEN_CASES[dim]
    lo, hi = [-0.3] * dim, [0.7 + 0.05 * a for a in range(dim)]
    rng = np.random.default_rng(dim)
    x0 = rng.uniform(lo, hi, (n, dim))
    x0[0] = lo  # on the boundary: inside, not escaped
    x0[1] = hi
    x = vec_field(x0)
    ns = NeighborSearch(dim, n, lo, hi, support, (False,) * dim, 128)
    ns.build(x, [])
    assert ns.escaped() == 0
    check_against_brute_force(ns, x.to_numpy(), lo, hi, (False,) * dim)
    # the particles only moved in memory
    np.testing.assert_array_equal(np.sort(x.to_numpy(), axis=0), np.sort(as_fp(x0), axis=0))


# ---------------------------------------------------------------- periodic boxes


@pytest.mark.parametrize(
    "dim, periodic",
    [(1, (True,)), (2, (True, False)), (2, (True, True)), (3, (False, True, False)), (3, (True, True, True))],
)
def test_periodic_matches_minimum_image_brute_force(dim, periodic):
    n, support = OPEN_CASES[dim]
    lo = np.array([-0.5, 0.0, 0.25][:dim])
    hi = lo + np.array([1.0, 0.93, 0.87][:dim])  # L / support not an integer: cells larger than support
    rng = np.random.default_rng(10 + dim)
    x0 = rng.uniform(lo, hi, (n, dim))
    # a pair across each periodic boundary, and particles outside the box on periodic axes
    for a, p in enumerate(periodic):
        if p:
            x0[2 * a, a] = lo[a] + 0.1 * support
            x0[2 * a + 1, a] = hi[a] - 0.1 * support
            x0[2 * a + 1, [b for b in range(dim) if b != a]] = x0[2 * a, [b for b in range(dim) if b != a]]
            x0[10 + a, a] = hi[a] + 0.3 * (hi[a] - lo[a])
            x0[20 + a, a] = lo[a] - 1.7 * (hi[a] - lo[a])
    pid = ti.field(ti.i32, n)
    pid.from_numpy(np.arange(n, dtype=np.int32))
    x = vec_field(x0)
    ns = NeighborSearch(dim, n, lo, hi, support, periodic, 128)
    ns.build(x, [pid])

    assert ns.escaped() == 0
    xs = x.to_numpy()
    for a, p in enumerate(periodic):
        if p:
            assert np.all((xs[:, a] >= lo[a]) & (xs[:, a] < hi[a])), "positions wrapped into [lo, hi)"
    # wrapped positions are the originals shifted by whole periods
    shift = xs - x0[pid.to_numpy()]
    length = hi - lo
    periods = shift / length
    np.testing.assert_allclose(periods, np.round(periods), atol=1e-5)
    for a, p in enumerate(periodic):
        if not p:
            assert np.all(np.round(periods[:, a]) == 0)

    check_against_brute_force(ns, xs, lo, hi, periodic)
    # the pair placed across each periodic boundary was found
    inv = np.argsort(pid.to_numpy())
    nb, count = ns.neighbors.to_numpy(), ns.count.to_numpy()
    for a, p in enumerate(periodic):
        if p:
            i, j = inv[2 * a], inv[2 * a + 1]
            assert j in nb[i, : count[i]] and i in nb[j, : count[j]]


def test_three_periodic_cells_list_each_neighbour_once():
    """With exactly 3 cells per periodic axis, all 9 neighbour cells are distinct: no double counting."""
    n, support = 60, 0.3
    lo, hi = [0.0, 0.0], [0.95, 0.95]  # 3 cells of 0.3167 per axis
    x0 = np.random.default_rng(3).uniform(lo, hi, (n, 2))
    x = vec_field(x0)
    ns = NeighborSearch(2, n, lo, hi, support, (True, True), 64)
    assert ns.n_cells == (3, 3)
    ns.build(x, [])
    check_against_brute_force(ns, x.to_numpy(), lo, hi, (True, True))


def test_pair_vector_and_wrap_funcs():
    lo, hi = [-1.0, 0.0], [1.0, 3.0]
    ns = NeighborSearch(2, 4, lo, hi, 0.5, (True, False), 8)
    xi = vec_field(np.array([[-0.9, 0.5], [0.9, 2.5], [2.5, 1.0], [-3.2, -0.4]]))
    xj = vec_field(np.array([[0.9, 0.3], [-0.9, 0.5], [0.0, 1.0], [0.0, 0.0]]))
    r = ti.Vector.field(2, float, 4)
    w = ti.Vector.field(2, float, 4)

    @ti.kernel
    def apply():
        for k in range(4):
            r[k] = ns.pair_vector(xi[k], xj[k])
            w[k] = ns.wrap(xi[k])

    apply()
    np.testing.assert_allclose(r.to_numpy(), [[0.2, 0.2], [-0.2, 2.0], [0.5, 0.0], [0.8, -0.4]], atol=1e-6)
    np.testing.assert_allclose(w.to_numpy(), [[-0.9, 0.5], [0.9, 2.5], [0.5, 1.0], [0.8, -0.4]], atol=1e-6)


# ---------------------------------------------------------------- reordering


def test_fields_follow_the_particles_and_cells_are_sorted():
    n, dim, support = 500, 2, 0.1
    lo, hi = [0.0, 0.0], [1.0, 1.0]
    rng = np.random.default_rng(7)
    x0 = rng.uniform(lo, hi, (n, dim))
    x = vec_field(x0)
    v = vec_field(x0)  # velocity = initial position: must stay equal to x
    pid = ti.field(ti.i32, n)
    pid.from_numpy(np.arange(n, dtype=np.int32))
    mass = ti.field(float, n)
    mass.from_numpy(as_fp(2.0 * np.arange(n)))
    kind = ti.field(ti.u8, n)
    kind.from_numpy((np.arange(n) % 3).astype(np.uint8))
    tensor = ti.Matrix.field(2, 2, float, n)
    tensor.from_numpy(as_fp(np.arange(n)[:, None, None] * np.ones((1, 2, 2))))
    rows = ti.field(ti.i32, (n, 3))  # a field with a second dimension: rows move as a whole
    rows.from_numpy(np.arange(n, dtype=np.int32)[:, None] + np.arange(3, dtype=np.int32)[None, :])
    fields = [v, pid, mass, kind, tensor, rows]

    ns = NeighborSearch(dim, n, lo, hi, support, (False, False), 64)
    for _ in range(3):
        ids_before = pid.to_numpy()
        ns.build(x, fields)
        ids = pid.to_numpy()
        assert np.array_equal(np.sort(ids), np.arange(n))
        np.testing.assert_array_equal(ids, ids_before[ns.order.to_numpy()])
        xs = x.to_numpy()
        np.testing.assert_array_equal(xs, v.to_numpy())
        np.testing.assert_array_equal(mass.to_numpy(), 2.0 * ids)
        np.testing.assert_array_equal(kind.to_numpy(), ids % 3)
        np.testing.assert_array_equal(tensor.to_numpy()[:, 1, 0], ids)
        np.testing.assert_array_equal(rows.to_numpy(), ids[:, None] + np.arange(3)[None, :])
        cell = ns.cell_id.to_numpy()
        assert np.all(np.diff(cell) >= 0), "particles sorted by cell"
        same_cell = np.diff(cell) == 0
        assert np.all(np.diff(ns.order.to_numpy())[same_cell] > 0), "stable within a cell"
        start = ns.cell_start.to_numpy()
        np.testing.assert_array_equal(start[cell], np.searchsorted(cell, cell, side="left"))
        assert start[-1] == n
        # cell of each particle from its position (cells of size support, starting at lo - support)
        c = np.floor((xs - (np.array(lo) - support)) / support).astype(int)
        c = np.clip(c, 0, np.array(ns.n_cells) - 1)
        np.testing.assert_array_equal(cell, c[:, 0] * ns.n_cells[1] + c[:, 1])
        check_against_brute_force(ns, xs, lo, hi, (False, False))
        # move the particles a little and go again (scratch buffers are reused)
        x.from_numpy(as_fp((xs + rng.normal(0.0, 0.02, xs.shape)).clip(0.0, 1.0)))
        v.copy_from(x)
    assert len(ns._bindings) == 1  # the same fields reuse one compiled build and its scratch buffers


def test_build_is_deterministic():
    n = 800
    x0 = np.random.default_rng(11).uniform(0.0, 1.0, (n, 2))
    ns = NeighborSearch(2, n, [0.0, 0.0], [1.0, 1.0], 0.08, (False, True), 64)
    results = []
    for _ in range(2):
        x = vec_field(x0)
        ns.build(x, [])
        count, nb = ns.count.to_numpy(), ns.neighbors.to_numpy()
        lists = [nb[i, : count[i]].tolist() for i in range(n)]
        results.append((x.to_numpy(), ns.order.to_numpy(), lists))
    np.testing.assert_array_equal(results[0][0], results[1][0])
    np.testing.assert_array_equal(results[0][1], results[1][1])
    assert results[0][2] == results[1][2]


def test_cell_start_is_the_exclusive_prefix_sum_over_many_scan_blocks():
    n = 3000
    x = vec_field(np.random.default_rng(4).uniform(0.0, 1.0, (n, 2)))
    ns = NeighborSearch(2, n, [0.0, 0.0], [1.0, 1.0], 0.01, (False, False), 16)
    assert ns.total_cells > 20 * ns._scan_block
    ns.build(x, [])
    per_cell = np.bincount(ns.cell_id.to_numpy(), minlength=ns.total_cells)
    np.testing.assert_array_equal(ns.cell_start.to_numpy(), np.concatenate([[0], np.cumsum(per_cell)]))


def test_order_inside_a_cell_does_not_depend_on_atomic_slot_order():
    """Slots inside a cell come from atomics (thread timing); the sort must undo any such order."""
    n = 400
    x = vec_field(np.random.default_rng(12).uniform(0.0, 1.0, (n, 2)))
    ns = NeighborSearch(2, n, [0.0, 0.0], [1.0, 1.0], 0.2, (False, False), 128)
    ns._assign_cells(x)
    cell = ns._unsorted_cell.to_numpy()
    slot = ns._slot_in_cell.to_numpy()
    size = np.bincount(cell, minlength=ns.total_cells)
    ns._slot_in_cell.from_numpy((size[cell] - 1 - slot).astype(np.int32))  # reversed hand-out order
    ns._scan_kernel()
    ns._sort_by_cell()
    order = ns.order.to_numpy()
    assert np.array_equal(np.sort(order), np.arange(n))
    assert np.all(np.diff(cell[order]) >= 0)
    assert np.all(np.diff(order)[np.diff(cell[order]) == 0] > 0)


# ---------------------------------------------------------------- guards


def test_escaped_particles_are_counted_and_clamped():
    n = 200
    lo, hi = [0.0, 0.0], [1.0, 1.0]
    x0 = np.random.default_rng(5).uniform(lo, hi, (n, 2))
    x0[:6] = [[-0.2, 0.5], [1.3, 0.5], [0.5, -50.0], [0.5, 1e6], [-1e9, -1e9], [np.nan, 0.5]]
    x = vec_field(x0)
    ns = NeighborSearch(2, n, lo, hi, 0.1, (False, False), 64)
    ns.build(x, [])
    assert ns.escaped() == 6
    xs = x.to_numpy()
    inside = np.all(np.isfinite(xs), axis=1)
    assert np.all(ns.count.to_numpy()[~inside] == 0)
    # the in-box particles still get exact lists
    nb, count = ns.neighbors.to_numpy(), ns.count.to_numpy()
    sub = np.nonzero(inside)[0]
    dist = np.linalg.norm(xs[sub][:, None] - xs[sub][None], axis=-1)
    for a, i in enumerate(sub):
        near = {int(sub[b]) for b in np.nonzero((dist[a] < 0.1 * (1 - TOL)) & (sub != i))[0]}
        assert near <= set(nb[i, : count[i]].tolist())

    # periodic axes never count as escape; the open axis does
    ns_p = NeighborSearch(2, n, lo, hi, 0.1, (True, False), 64)
    x0[:6] = [[-0.2, 0.5], [1.3, 0.5], [7.5, 0.5], [0.5, 1.5], [0.5, -0.5], [np.inf, 0.5]]
    x = vec_field(x0)
    ns_p.build(x, [])
    assert ns_p.escaped() == 3  # two off the open axis, one non-finite


def test_overflow_is_reported_and_lists_stay_valid():
    rng = np.random.default_rng(9)
    cluster = 0.5 + rng.uniform(-0.01, 0.01, (11, 2))  # 11 particles, 10 neighbours each
    # a ring of 32 in the cluster's neighbour cells: candidates, never neighbours of the cluster
    angle = np.linspace(0.0, 2.0 * np.pi, 32, endpoint=False)
    ring = 0.5 + 0.2 * np.stack([np.cos(angle), np.sin(angle)], axis=1)
    x0 = np.concatenate([cluster, ring])
    n = len(x0)
    lo, hi = [0.0, 0.0], [1.0, 1.0]
    support = 0.15
    pid = ti.field(ti.i32, n)

    def run(cap, extra_cluster=0):
        pts = x0.copy()
        pts[11 : 11 + extra_cluster] = 0.5 + rng.uniform(-0.01, 0.01, (extra_cluster, 2))
        x = vec_field(pts)
        pid.from_numpy(np.arange(n, dtype=np.int32))
        ns = NeighborSearch(2, n, lo, hi, support, (False, False), cap)
        ns.build(x, [pid])
        xs = x.to_numpy()
        count, nb = ns.count.to_numpy(), ns.neighbors.to_numpy()
        for i in range(n):  # truncated or not, a list holds distinct true neighbours
            found = nb[i, : count[i]]
            assert len(set(found.tolist())) == count[i] and i not in found
            assert np.all(np.linalg.norm(xs[found] - xs[i], axis=1) < support)
        return ns, count, pid.to_numpy()

    ns, count, ids = run(cap=10)  # exactly full: not an overflow
    assert not ns.overflowed() and ns.max_count() == 10
    assert np.all(count[ids < 11] == 10)

    ns, count, ids = run(cap=10, extra_cluster=19)  # 30 particles in the cluster
    assert ns.overflowed() and ns.max_count() == 29
    assert np.all(count[ids < 30] == 10)


def test_short_periodic_axis_is_a_config_error():
    with pytest.raises(ConfigError, match="periodic length must be >= 3 support radii"):
        NeighborSearch(2, 10, [0.0, 0.0], [1.0, 1.0], 0.4, (True, False), 16)
    NeighborSearch(2, 10, [0.0, 0.0], [1.0, 1.0], 0.4, (False, False), 16)  # open axes are fine


def test_group_pairs_are_left_out():
    """With a group field (walls = 1), wall-wall pairs are skipped; every pair with a fluid member stays."""
    n = 600
    rng = np.random.default_rng(21)
    xs = rng.uniform(0.0, 1.0, (n, 2))
    grp_np = (rng.uniform(size=n) < 0.5).astype(np.int32)
    x = vec_field(xs)
    grp = ti.field(ti.i32, n)
    grp.from_numpy(grp_np)
    pid = ti.field(ti.i32, n)
    pid.from_numpy(np.arange(n, dtype=np.int32))
    ns = NeighborSearch(2, n, [0.0, 0.0], [1.0, 1.0], 0.1, (False, False), 64, group=grp)
    ns.build(x, [grp, pid])
    xn, g, ids = x.to_numpy().astype(np.float64), grp.to_numpy(), pid.to_numpy()
    assert np.array_equal(g, grp_np[ids])  # the group field was permuted with the particles
    dist = np.linalg.norm(xn[:, None] - xn[None], axis=-1)
    np.fill_diagonal(dist, np.inf)
    count, nb = ns.count.to_numpy(), ns.neighbors.to_numpy()
    for i in range(n):
        found = set(nb[i, : count[i]].tolist())
        expected = {j for j in np.where(dist[i] < 0.1 - 1e-6)[0] if not (g[i] and g[j])}
        maybe = {j for j in np.where(np.abs(dist[i] - 0.1) <= 1e-6)[0]}
        assert expected <= found <= expected | maybe
        assert not any(g[i] and g[j] for j in found)


# ---------------------------------------------------------------- access 'cells': the walk over the sorted cells


@ti.data_oriented
class _Recorder:
    """What a pair loop sees through `for_each_neighbor`: the neighbours it visits, in visit order."""

    def __init__(self, ns: NeighborSearch, x, capacity: int = 128) -> None:
        self.ns = ns
        self.x = x
        self.found = ti.field(ti.i32, (ns.n, capacity))
        self.count = ti.field(ti.i32, ns.n)
        self.bad_r = ti.field(ti.i32, ())  # visits whose r_ab is not pair_vector(x_a, x_b)

    @ti.kernel
    def walk(self):
        for a in range(self.ns.n):
            visit = ti.Struct(c=0, xa=self.x[a])
            self.ns.for_each_neighbor(a, self.x, self.record, visit)
            self.count[a] = visit.c

    @ti.func
    def record(self, a, b, r_ab, visit: ti.template()):
        if visit.c < self.found.shape[1]:
            self.found[a, visit.c] = b
        if (r_ab - self.ns.pair_vector(visit.xa, self.x[b])).norm() > 0.0:
            self.bad_r[None] += 1
        visit.c += 1


@pytest.mark.parametrize(
    "dim, periodic",
    [(1, (False,)), (2, (False, False)), (3, (False, False, False)), (1, (True,)), (2, (True, False)),
     (2, (True, True)), (3, (False, True, False)), (3, (True, True, True))],
)
def test_cell_walk_visits_the_list_entries_in_list_order(dim, periodic):
    """Every pair loop's sum is the same with access 'cells' as with 'lists': `for_each_neighbor` visits
    exactly the listed neighbours (self never, each once, across periodic faces too), in the lists' order,
    with r_ab = pair_vector(x_a, x_b), in both accesses."""
    n, support = OPEN_CASES[dim]
    lo = np.array([-0.5, 0.0, 0.25][:dim])
    hi = lo + np.array([1.0, 0.93, 0.87][:dim])
    x = vec_field(np.random.default_rng(20 + dim).uniform(lo, hi, (n, dim)))
    lists = NeighborSearch(dim, n, lo, hi, support, periodic, 128)
    cells = NeighborSearch(dim, n, lo, hi, support, periodic, 128, access="cells")
    assert cells.neighbors is None and cells.count is None  # nothing stored
    lists.build(x, [])
    cells.build(x, [])  # same order: the sort of sorted particles is the identity
    np.testing.assert_array_equal(cells.order.to_numpy(), np.arange(n))
    c_lists, nb_lists = lists.count.to_numpy(), lists.neighbors.to_numpy()
    assert c_lists.mean() > 10  # the case has neighbours to find
    for ns in (lists, cells):  # the one iterator, either access
        rec = _Recorder(ns, x)
        rec.walk()
        c_seen, nb_seen = rec.count.to_numpy(), rec.found.to_numpy()
        np.testing.assert_array_equal(c_seen, c_lists)
        for i in range(n):
            np.testing.assert_array_equal(nb_seen[i, : c_seen[i]], nb_lists[i, : c_lists[i]])
        assert rec.bad_r[None] == 0
    assert not cells.overflowed() and cells.max_count() == 0


def test_unknown_access_is_an_error():
    with pytest.raises(ConfigError, match="allowed: lists, cells"):
        NeighborSearch(2, 10, [0, 0], [1, 1], 0.1, (False, False), 8, access="verlet")
