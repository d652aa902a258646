"""The trilinear-topology tables (issue 22, in progress): the stored entries
are the derivation's, and the flattened kernel table says the same as they do."""

from __future__ import annotations

import pytest

from isoconvert.extract import trilinear as tl
from isoconvert.extract.tables import marching_cubes_table


def test_stored_entries_equal_the_derivation_on_a_spread_of_entries():
    """trilinear_tables.py is generated (about 50 s for all of it); every
    thirteenth reachable entry is derived again here and must be identical."""
    stored = tl.stored_entries()
    keys = tl.reachable_entries()
    assert sorted(stored) == sorted(keys)
    for key in keys[::13]:
        _, corners, disks, tubes = tl.entry(*key)
        assert stored[key][0] == tuple(tuple(c) for c in corners)
        assert [(list(map(list, t)), list(m)) for t, m in stored[key][1]] == [
            (list(map(list, t)), list(m)) for t, m in disks
        ]
        assert stored[key][2] == {
            pair: (tuple(map(tuple, t)), tuple(m)) for pair, (t, m) in tubes.items()
        }


def test_configurations_without_a_choice_keep_the_default_table():
    """Where no face is ambiguous and every sign's corners meet on the boundary,
    the trilinear surface is the fixed rule's: one disk, the same triangles."""
    counts, table = marching_cubes_table("separate-positive")
    free = [c for c in range(256) if not tl.needs_interior_test(c)]
    assert len(free) + int(tl.kernel_table()["special"].sum()) == 256
    for config in free:
        _, _, disks, tubes = tl.entry(config, 0)
        assert not tubes
        triangles = [t for d, inner in disks for t in d]
        assert all(not inner for _, inner in disks)
        assert triangles == [tuple(t) for t in table[config, : counts[config]].tolist()]


@pytest.mark.parametrize("key", [(0b01000001, 0), (0b10000001, 0), (0b00100001, 4)])
def test_kernel_table_rows_give_back_the_stored_pieces(key):
    """The flattened arrays the kernel reads hold each piece of an entry."""
    k = tl.kernel_table()
    config, faces = key
    if key not in tl.stored_entries():
        pytest.skip(f"{key} is not reachable")
    corners, disks, tubes = tl.stored_entries()[key]
    e = int(k["entry"][64 * config + faces])
    assert e >= 0 and k["loops"][e] == len(corners)

    def piece(p):
        t = k["tris"][k["piece_tris"][p] : k["piece_tris"][p + 1]]
        m = k["inner"][k["piece_inner"][p] : k["piece_inner"][p + 1]]
        return tuple(map(tuple, t.tolist())), tuple(m.tolist())

    for i, d in enumerate(disks):
        assert piece(int(k["disk"][e, i])) == d
    for pair, t in tubes.items():
        assert piece(int(k["tube"][e, tl.LOOP_PAIRS.index(pair)])) == t


def test_every_piece_names_only_its_edges_and_slots():
    """Triangles use cube edges 0..11 and interior slots the piece declares;
    no cube needs more than 16 interior vertices (the id scheme's room)."""
    k = tl.kernel_table()
    for p in range(len(k["piece_tris"]) - 1):
        t = k["tris"][k["piece_tris"][p] : k["piece_tris"][p + 1]]
        declared = k["piece_inner"][p + 1] - k["piece_inner"][p]
        assert t.min() >= 0 and t.max() < tl.INNER + declared

    def slots(p):
        return int(k["piece_inner"][p + 1] - k["piece_inner"][p]) if p >= 0 else 0

    def most(e, free):
        # the most interior vertices of any pairing of the loops into tubes
        if not free:
            return 0
        i, rest = free[0], free[1:]
        best = slots(k["disk"][e, i]) + most(e, rest)
        for j in rest:
            tube = k["tube"][e, tl.LOOP_PAIRS.index((i, j))]
            best = max(best, slots(tube) + most(e, [r for r in rest if r != j]))
        return best

    worst = max(most(e, list(range(int(k["loops"][e])))) for e in range(len(k["loops"])))
    assert 0 < worst < 16
