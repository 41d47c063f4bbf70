"""flocklab's service layer: the CLI, run artifacts, the HTTP job service.

The engine (`kernels`, Taichi) is imported only where a simulation actually runs: the
CLI's `run` command and the service's worker processes, never the API process.
"""
