"""The flight processes: the service runtime every process shares (``runtime``), the input
streams navigation and the controller share (``streams``: pairing by time, fault queues, the
grace after the final clock), the environment (truth, clock, exostate), navigation, the
controller service (``controller``) and its pure control law (``control``), and the one-process
baseline that runs the same code without a bus (``inprocess``).  The runnable process modules
are ``environment``, ``navigation`` and ``controller``.

May import: ``ddvi_core`` and every library layer (``services.interface``, ``services.bus``,
``services.config``, ``services.model``). Not ``services.ground``. Each process module is
imported by its module path; this package re-exports nothing.
"""
