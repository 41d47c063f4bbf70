"""Pictures of runs, jobs and sweeps: paper-style snapshots, observables plots, movies.

Reads the folders `service.execute.execute_to_dir` writes (`scenario.json`,
`summary.json`, `observables.csv`, `trajectory.h5`) and a sweep's `table.csv` +
`sweep.json`. Modules: `run_data` (reading), `geometry` (edges, obstacles, leaders),
`snapshot`, `plots`, `movie` (drawing), `cli` (`flocklab render`), `worker` (the child
process the service draws in). Nothing is imported here: matplotlib (the `flocklab[plot]`
extra) loads only when something is drawn, and the service draws in a child process,
never in the API process.
"""
