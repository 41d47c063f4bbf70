"""M4: Xi-Abed formation control, F1 (offsets from a moving leader) and F2 (a leader point
with pairwise repulsion). `kernel` is the per-step path, on `forces` (f, g and the leader
term), `dense` (the coarse dense regime), `path` (leader paths), `schedule` and `shapes`
(formation offsets and their changes) and `props` (properties D1-D3); `fused` (with
`fused_terms` and `fused_observe`) is the small-N batch."""
