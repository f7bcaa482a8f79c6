"""Ground tools, one subpackage per job: ``launch`` (the launcher that runs a deployment, its
supervision and lifecycle, the run folder and its bus, network namespaces, fault injection),
``storage`` (the monitor's recording, on a disk that may fill, and whether the record is
whole), ``analysis`` (the run's data, what the ground believes of it, the run report and its
recovery from a recording), ``monitoring`` (the monitor, its live status and live view, and
the taps on a running mission), ``sweeps`` (``ddvi sweep``) and ``campaign`` (Monte Carlo
campaigns: dispersions, a Dask cluster, a result table and its report).

May import: everything below it (``ddvi_core``, the library layers, ``services.flight``).
Each tool is imported by its module path, so a command loads only what it needs; this package
re-exports nothing.
"""
