"""The fused batches' per-replica cell list: a stable counting sort inside one CPU task.

A fused batch (kernels/batch.py) runs each replica serially in one task, so its cell list
needs no atomics: the family's own pass gives every agent i of the replica (rows a0 ..
a0 + n) a cell, writing `cell[i]` and counting it in `cstart[c0 + cell + 1]` (after
`clear_cells`), and `make_cell_sort(place)` turns the counts into the list: `cidx[a0 + k]`
is the agent in slot k, slots in cell order and, within a cell, in id order, and cell c
holds slots `cstart[c0 + c] .. cstart[c0 + c + 1]`. How a family sizes its cells (periodic
box, bounding box, hashed buckets) is its own; the sort is this one.

Taichi compiles `a[i] += v` on an array element to an atomic read-modify-write (a locked
instruction, a compare-and-swap loop for floats) even in a serial inner loop, so the fused
kernels write `a[i] = a[i] + v`: the same value, at a tenth of the cost (the count and the
scan were a third of a small-N Vicsek step).
"""

import taichi as ti

# The CPU backend cuts a parallel loop into tasks of 512 iterations: a fused kernel loops
# over replicas * SPREAD and works where t % SPREAD == 0, one replica per task.
SPREAD = 512


@ti.func
def clear_cells(c0, nb, cstart: ti.template()):
    """Zero the counts of the replica's nb cells (and the end marker)."""
    for c in range(c0, c0 + nb + 1):
        cstart[c] = 0


def make_cell_sort(place=None):
    """(sort, identity): `sort(a0, n, c0, nb, cell, cstart, cidx, S)` finishes the counting
    sort of the counted cells; `identity(a0, n, cidx, S)` is the order without cells (slot
    k holds agent k: the all-pairs visit). Both call `place(slot, agent, S)` for each agent
    as it lands (a family copying its state into slot order on the way), if given."""
    placing = place is not None  # decided here: Taichi scope has no `is`

    @ti.func
    def sort(a0, n, c0, nb, cell: ti.template(), cstart: ti.template(),
             cidx: ti.template(), S: ti.template()):
        for c in range(c0 + 1, c0 + nb + 1):
            cstart[c] = cstart[c] + cstart[c - 1]
        for i in range(a0, a0 + n):  # cstart[c] as the fill pointer of cell c
            slot = c0 + cell[i]
            k = cstart[slot]
            cidx[a0 + k] = i
            if ti.static(placing):
                place(a0 + k, i, S)
            cstart[slot] = k + 1
        for m in range(nb):  # shift back: start[c] = end[c - 1], from the top
            c = c0 + nb - m
            cstart[c] = cstart[c - 1]
        cstart[c0] = 0

    @ti.func
    def identity(a0, n, cidx: ti.template(), S: ti.template()):
        for k in range(a0, a0 + n):
            cidx[k] = k
            if ti.static(placing):
                place(k, k, S)

    return sort, identity
