"""Ground tools: the launcher that runs a deployment (its lifecycle: ``lifecycle``), the monitor
and its recording (on a disk that may fill: ``disk``), the run report (its recovery from a
recording: ``recover``; the services' counters it believes: ``claims``; whether its record is
whole: ``record``), fault injection, sweeps, Monte Carlo campaigns (the ``campaign`` package:
dispersions, a Dask cluster, a result table and its report) and network namespaces.

May import: everything below it (``ddvi_core``, the library layers, ``services.flight``).
Each tool is imported by its module path, so a command loads only what it needs; this package
re-exports nothing.
"""
