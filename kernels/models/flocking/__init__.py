"""M2 (Tanner-Jadbabaie-Pappas flocking, fixed and switching topology) and M3 (Tanner's
obstacles and navigation function). `kernel` is M2's per-step path and `obstacles` M3's,
built on `forces` (the grid kernels), `navigation` (the obstacle grid and potential),
`potentials`, `topology` (fixed graphs) and `observe` (host-side observables); `fused` is
the small-N batch of both."""
