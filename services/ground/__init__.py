"""Ground tools: the launcher that runs a deployment, the monitor and its recording, the run
report, fault injection, sweeps and network namespaces.

May import: everything below it (``ddvi_core``, the library layers, ``services.flight``).
Each tool is imported by its module path, so a command loads only what it needs; this package
re-exports nothing.
"""
