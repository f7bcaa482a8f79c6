"""Launching a run and acting on it: ``ddvi run``'s launcher (``launcher``), its watch over the
services while the mission flies (``supervisor``), the services as processes (``processes``),
stop signals and the run's verdict (``lifecycle``), the run folder (``runfolder``) and its bus
(``credentials``), separate network hosts (``netns``: ``ddvi netns``) and faults injected from
the ground (``faults``: ``ddvi fault``)."""
