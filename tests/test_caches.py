"""The one byte budget of a run's caches (femphase.caches)."""

import gc

import numpy as np
import pytest
import scipy.sparse as sp

from femphase.caches import ByteBudget, nbytes_of


def test_entries_of_all_caches_are_dropped_least_recently_used_first():
    budget = ByteBudget(3000)
    blocks, solvers = budget.cache("blocks"), budget.cache("solvers")
    blocks.put("a", np.zeros(100))     # 800 bytes each
    solvers.put("b", np.zeros(100))
    blocks.put("c", np.zeros(100))
    assert blocks.get("a") is not None  # "a" used again: "b" is now the oldest
    solvers.put("d", np.zeros(100))     # 3200 > 3000: one must go
    assert "b" not in solvers and {"a", "c"} <= set(blocks._values) and "d" in solvers
    assert budget.used == 2400 == blocks.nbytes + solvers.nbytes
    assert budget.usage() == {"blocks": 1600, "solvers": 800}


def test_an_entry_larger_than_the_budget_is_kept_alone_and_a_lower_limit_drops_at_once():
    budget = ByteBudget(1000)
    cache = budget.cache("blocks")
    cache.put("small", np.zeros(10))
    cache.put("large", np.zeros(1000))  # 8000 bytes: everything else goes, it stays
    assert list(cache._values) == ["large"] and budget.used == 8000
    budget.limit = 10_000
    cache.put("small", np.zeros(10))
    budget.limit = 100
    assert len(cache) == 1 and budget.used <= 8000  # lowering drops the oldest at once
    with pytest.raises(ValueError, match="whole number of bytes"):
        budget.limit = -1


def test_a_cache_garbage_collected_gives_its_bytes_back():
    budget = ByteBudget(10**6)
    cache = budget.cache("advection solvers")
    cache.put(1, np.zeros(1000))
    assert budget.used == 8000
    del cache
    gc.collect()
    assert budget.used == 0 and len(budget) == 0


def test_replacing_and_popping_keep_the_count():
    budget = ByteBudget(10**6)
    cache = budget.cache("layout")
    cache.put("last", np.zeros(10))
    cache.put("last", np.zeros(20))
    assert budget.used == 160
    assert cache.setdefault("last", lambda: pytest.fail("built again")).size == 20
    cache.pop("last")
    assert budget.used == 0 and "last" not in cache


def test_sizes_are_measured_or_refused():
    matrix = sp.random(50, 50, density=0.1, format="csr", random_state=1)
    assert nbytes_of(matrix) == matrix.data.nbytes + matrix.indices.nbytes + matrix.indptr.nbytes
    assert nbytes_of((np.zeros(3), None, 2.0, [np.zeros(2)])) == 40
    with pytest.raises(TypeError, match="cannot measure"):
        nbytes_of(object())


def test_row_shift_phases_are_kept_for_the_current_runs_only():
    # windows regroup as a shear carries particles past each other; a run of windows left
    # is rarely met again, and kept by LRU alone such runs reached 85 MiB
    from femphase.domains.grid.advection import RowShift, row_runs
    from femphase.run.simulation import Simulation
    from femphase.scene import scene_from_dict

    scene = scene_from_dict({
        "domain": {"Lx": 60.0, "Ly": 40.0},
        "particles": {"layout": "list", "centres": [[10.0, 12.0], [30.0, 20.0], [50.0, 28.0]]},
        "output": {"fields": False},
        "phases": [{"duration": 400.0, "dt": 10.0, "frame_interval": 400.0, "flow": {"type": "shear", "rate": 1.0}}]})
    seen = []
    advect = RowShift.advect

    def recorded(self, phi, layout, time):
        out = advect(self, phi, layout, time)
        runs = {(nx, members.tobytes(), heights.tobytes()) for *_, members, heights, nx in row_runs(layout)}
        seen.append((len(self._stacks), {(k[0], k[2], k[3]) for k in self._stacks._values} <= runs, len(runs)))
        return out

    RowShift.advect = recorded
    try:
        Simulation(scene).run(scene.initial_state())
    finally:
        RowShift.advect = advect
    assert seen and all(kept and count <= 2 * runs for count, kept, runs in seen)
    assert scene.domain.caches.used <= scene.domain.caches.limit
