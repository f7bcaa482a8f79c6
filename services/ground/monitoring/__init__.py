"""Watching a run: the monitor that records every message and writes the report (``monitor``),
when its recording ends (``ending``), its live status (``status``), the live view served to
Foxglove (``live``, ``live_address``), and ``ddvi monitor``'s taps on a running mission
(``tap``, ``live_tap``, ``run_keys``)."""
