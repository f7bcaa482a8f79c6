"""Sweeps (``ddvi sweep``): the mission over a range of link impairments, or of navigation noise
and model mismatch (``sweep``), and their results as a table and a plot (``sweep_table``)."""
