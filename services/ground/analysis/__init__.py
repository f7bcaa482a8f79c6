"""A run's data and its report: what the monitor learns from the bus (``rundata``), the services'
counters it believes (``claims``) and the messages it refuses (``refusals``), how the run ended
(``outcome``), the one scoring of a deputy (``scoring``), the report and its figures
(``report``, ``figures``, ``gain_figure``, and what they share: ``figure_canvas``), and
``ddvi report``: the report again from a recording (``replay``), recovering one cut short
(``recover``)."""
