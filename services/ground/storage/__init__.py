"""What a run keeps on disk: the monitor's recording, an MCAP file, and reading one back
(``recording``), the run folder's disk that may fill (``disk``), and whether the run's record is
whole (``record``)."""
