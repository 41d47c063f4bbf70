"""The engine's shared building blocks, used by every model family.

`grid` (uniform cells over the periodic box or hashed over the plane, the stable counting
sort and the neighbour visitor), `plane_grid` (the dense row-by-row grid and the plane's
choice between it and the hashed one), `state` (agent arrays kept in grid order), `graph`
(union-find components of the metric graph), `rng` (counter-based noise), `initial`
(initial states), `integrate` (RK4), `params` (named parameter slots), `cells` (the fused
batches' per-replica counting sort), `observables` (numpy statistics shared by families).
"""
