"""M2 (Tanner-Jadbabaie-Pappas flocking, fixed and switching topology) and M3 (Tanner's
obstacles and navigation function), two assemblies of one flock: `kernel` holds the flock
(`Flock`) and M2, `obstacles` M3; the parts they choose are `radius` (one R or per-agent
R_i under eq. 4) and `mission` (none, or the navigation function and damping). Beneath
them: `forces` (the grid kernels), `navigation` (the obstacle grid and potential),
`potentials`, `topology` (fixed graphs) and `observe` (host-side observables); `fused` is
the small-N batch of both."""
